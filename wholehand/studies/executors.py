"""Run study jobs serially, in a process pool or on a Ray cluster, with a progress bar; each
result is reported as it arrives, and all come back in job order whatever the executor."""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from typing import Any

from tqdm import tqdm

from wholehand.errors import ConfigError
from wholehand.studies.base import TrialJob

EXECUTORS = ("process", "serial", "ray")
"""Executor names accepted by :func:`execute`."""

_SINGLE_THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
"""Linear-algebra thread counts pinned to 1 in pool workers: the pool is the parallelism."""

ResultCallback = Callable[[int, dict[str, Any]], None]
"""``on_result(index, row)``: called in the calling process as each job finishes."""


PARENT_POLL = 0.5
"""How often a pool worker checks that the process that started it is alive [s]."""


def _die_with_parent(parent_pid: int) -> None:
    """Pool-worker initializer: exit as soon as the parent is gone (killed, even by SIGKILL),
    so no worker outlives the study that started it or keeps its pipes open."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL)
        os._exit(1)

    threading.Thread(target=watch, name="wholehand-parent-watch", daemon=True).start()


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
    on_result: ResultCallback | None = None,
) -> list[dict[str, Any]]:
    """``[run(job) for job in jobs]``, returned sorted by ``job.index`` whatever the executor.

    Jobs are submitted in the order of ``jobs`` (pass them in the order they should run; the
    list returned is sorted by index all the same). On an interruption (``KeyboardInterrupt``)
    or any other error, jobs not started are cancelled, the pool or Ray is shut down and the
    exception is re-raised: results already delivered to ``on_result`` are all that is kept.

    Args:
        jobs: the work.
        run: a picklable module-level function (it runs in worker processes).
        executor: ``"process"`` (a spawn-context :class:`ProcessPoolExecutor`), ``"serial"`` or
            ``"ray"``.
        workers: pool size; default one per core.
        progress: show a tqdm bar on stderr.
        desc: label of the progress bar.
        address: ``"ray"`` only: the cluster to connect to (e.g. ``"auto"`` or
            ``"ray://head:10001"``); None starts a local Ray instance for this run.
        on_result: called as ``on_result(job.index, row)`` in this process as soon as each job
            has finished, in completion order (e.g. to journal rows as they arrive).

    Raises:
        ConfigError: an unknown executor or ``workers < 1``.
    """
    if executor not in EXECUTORS:
        raise ConfigError(f"executor {executor!r} is unknown; use one of {list(EXECUTORS)}")
    workers = default_workers() if workers is None else int(workers)
    if workers < 1:
        raise ConfigError(f"workers must be >= 1, got {workers}")
    results: dict[int, dict[str, Any]] = {}
    bar = tqdm(total=len(jobs), desc=desc, disable=not progress, unit="trial")

    def deliver(index: int, row: dict[str, Any]) -> None:
        results[index] = row
        bar.update()
        if on_result is not None:
            on_result(index, row)

    try:
        if executor == "ray":
            _execute_ray(jobs, run, deliver, address, workers)
        elif executor == "serial" or workers == 1 or len(jobs) <= 1:
            for job in jobs:
                deliver(job.index, run(job))
        else:
            _execute_pool(jobs, run, deliver, workers)
    finally:
        bar.close()
    return [results[job.index] for job in sorted(jobs, key=lambda j: j.index)]


def _execute_pool(
    jobs: Sequence[TrialJob],
    run: Callable[[TrialJob], dict[str, Any]],
    deliver: ResultCallback,
    workers: int,
) -> None:
    """Every job in a spawn-context process pool, submitted in order. On an interruption the
    pending jobs are cancelled, the running ones finish, and their results are still delivered."""
    saved = {k: os.environ.get(k) for k in _SINGLE_THREAD_ENV}
    os.environ.update({k: "1" for k in _SINGLE_THREAD_ENV})  # inherited by the workers
    try:
        ctx = multiprocessing.get_context("spawn")  # no fork of a process with solver threads
        pool = ProcessPoolExecutor(
            max_workers=min(workers, len(jobs)),
            mp_context=ctx,
            initializer=_die_with_parent,
            initargs=(os.getpid(),),
        )
        futures: dict[Future[dict[str, Any]], int] = {}
        delivered: set[int] = set()
        try:
            for job in jobs:
                futures[pool.submit(run, job)] = job.index
            for future in as_completed(futures):
                deliver(futures[future], future.result())
                delivered.add(futures[future])
        except KeyboardInterrupt:
            pool.shutdown(wait=True, cancel_futures=True)  # running trials finish (or abort)
            for future, index in futures.items():  # keep what finished meanwhile
                if index not in delivered and _finished_ok(future):
                    deliver(index, future.result())
            raise
        except BaseException:
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        pool.shutdown(wait=True)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _finished_ok(future: Future[dict[str, Any]]) -> bool:
    """Whether a future holds a result (not cancelled, not raised, e.g. on a worker's SIGINT)."""
    return future.done() and not future.cancelled() and future.exception() is None


def _execute_ray(
    jobs: Sequence[TrialJob],
    run: Callable[[TrialJob], dict[str, Any]],
    deliver: ResultCallback,
    address: str | None,
    workers: int,
) -> None:
    """Every job as one Ray task, submitted in order. With no Ray running, connects to
    ``address`` or starts a local instance of ``workers`` CPUs, and shuts it down afterwards.
    On an interruption the tasks not finished are cancelled."""
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
    pending: dict[Any, int] = {}
    try:
        task = ray.remote(num_cpus=1)(run)
        for job in jobs:
            pending[task.remote(job)] = job.index
        waiting = list(pending)
        while waiting:
            done, waiting = ray.wait(waiting, num_returns=1)
            for ref in done:
                deliver(pending.pop(ref), ray.get(ref))
    except BaseException:
        for ref in pending:  # not finished yet
            try:
                ray.cancel(ref)
            except Exception:  # noqa: BLE001 - best effort: Ray is shut down next
                pass
        raise
    finally:
        if started_here:
            ray.shutdown()
