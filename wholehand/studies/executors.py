"""Run study jobs serially, in a process pool or on a Ray cluster, with a progress bar; results in
job order whatever the executor."""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

from tqdm import tqdm

from wholehand.errors import ConfigError
from wholehand.studies.base import TrialJob

EXECUTORS = ("process", "serial", "ray")
"""Executor names accepted by :func:`execute`."""

_SINGLE_THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
"""Linear-algebra thread counts pinned to 1 in pool workers: the pool is the parallelism."""


def default_workers() -> int:
    """One worker per CPU core."""
    return os.cpu_count() or 1


def execute(
    jobs: Sequence[TrialJob],
    run: Callable[[TrialJob], dict[str, Any]],
    executor: str = "process",
    workers: int | None = None,
    progress: bool = True,
    desc: str = "trials",
    address: str | None = None,
) -> list[dict[str, Any]]:
    """``[run(job) for job in jobs]``, in job order whatever the executor.

    Args:
        jobs: the work.
        run: a picklable module-level function (it runs in worker processes).
        executor: ``"process"`` (a spawn-context :class:`ProcessPoolExecutor`) or ``"serial"``.
        workers: pool size; default one per core.
        progress: show a tqdm bar on stderr.
        address: ``"ray"`` only: the cluster to connect to (e.g. ``"auto"`` or
            ``"ray://head:10001"``); None starts a local Ray instance for this run.
    """
    if executor not in EXECUTORS:
        raise ConfigError(f"executor {executor!r} is unknown; use one of {list(EXECUTORS)}")
    workers = default_workers() if workers is None else int(workers)
    if workers < 1:
        raise ConfigError(f"workers must be >= 1, got {workers}")
    results: dict[int, dict[str, Any]] = {}
    bar = tqdm(total=len(jobs), desc=desc, disable=not progress, unit="trial")
    if executor == "ray":
        results = _execute_ray(jobs, run, bar, address, workers)
    elif executor == "serial" or workers == 1 or len(jobs) <= 1:
        for job in jobs:
            results[job.index] = run(job)
            bar.update()
    else:
        saved = {k: os.environ.get(k) for k in _SINGLE_THREAD_ENV}
        os.environ.update({k: "1" for k in _SINGLE_THREAD_ENV})  # inherited by the workers
        try:
            ctx = multiprocessing.get_context("spawn")  # no fork of a process with solver threads
            with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=ctx) as pool:
                futures = {pool.submit(run, job): job.index for job in jobs}
                for future in as_completed(futures):
                    results[futures[future]] = future.result()
                    bar.update()
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
    bar.close()
    return [results[job.index] for job in sorted(jobs, key=lambda j: j.index)]


def _execute_ray(
    jobs: Sequence[TrialJob],
    run: Callable[[TrialJob], dict[str, Any]],
    bar: tqdm,
    address: str | None,
    workers: int,
) -> dict[int, dict[str, Any]]:
    """Every job as one Ray task. With no Ray running, connects to ``address`` or starts a local
    instance of ``workers`` CPUs, and shuts it down afterwards."""
    try:
        import ray
    except ImportError as err:
        raise ConfigError("executor 'ray' needs Ray: pip install 'wholehand[ray]'") from err
    started_here = not ray.is_initialized()
    if started_here:
        single_thread = {k: "1" for k in _SINGLE_THREAD_ENV}
        ray.init(
            address=address,
            num_cpus=None if address else workers,
            include_dashboard=False,
            log_to_driver=False,
            runtime_env={"env_vars": single_thread},
        )
    try:
        task = ray.remote(num_cpus=1)(run)
        pending = {task.remote(job): job.index for job in jobs}
        results: dict[int, dict[str, Any]] = {}
        waiting = list(pending)
        while waiting:
            done, waiting = ray.wait(waiting, num_returns=1)
            for ref in done:
                results[pending[ref]] = ray.get(ref)
                bar.update()
        return results
    finally:
        if started_here:
            ray.shutdown()
