"""Run a study: expand its jobs, execute them, write ``trials.csv``, ``summary.json`` and a PNG.

Every row of ``trials.csv`` is one trial, sorted by its index in the study. Its columns are the
study's labels, every :class:`~wholehand.trials.trial.TrialSpec` field, the outcome (held, stages
reached, failure stage, contact counts, final object displacement) and, last, the wall-clock
timings (``TIMING_COLUMNS`` of :mod:`wholehand.studies.study_files`). Everything but the timings
is a function of the study, its size and its seed: the same seed gives the same rows whatever
the executor or worker count.

Long runs: while a study runs, every finished row is appended to the journal ``rows.jsonl``
(one JSON object a line, flushed per row). ``run_study(..., resume=True)`` reads the rows
already in the folder (journal and ``trials.csv``), matches them to the study's jobs by content
(:mod:`wholehand.studies.resume`) and runs only the rest; ``limit`` caps the trials run this
time. A run that ends with trials missing still writes its outputs, marked ``"complete": false``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from wholehand import registry
from wholehand.errors import ConfigError
from wholehand.grasps.store import grasps_from
from wholehand.provenance import provenance
from wholehand.studies.base import (
    DEFAULT_HAND,
    Study,
    TrialJob,
    only_jobs,
    with_grasps,
    with_methods,
)
from wholehand.studies.consistency import net_force_row
from wholehand.studies.dexgraspbench import load_test_row
from wholehand.studies.executors import execute
from wholehand.studies.folder_lock import study_folder_lock
from wholehand.studies.grasp_synthesis import generation_row
from wholehand.studies.models import model
from wholehand.studies.reach import episode_row
from wholehand.studies.resume import (
    content_key,
    continue_command,
    execution_order,
    failed_to_run,
    has_result,
    match_rows,
)
from wholehand.studies.rows import record_row, spec_columns
from wholehand.studies.study_files import (
    JOURNAL_NAME,
    folder_rows,
    journal_line,
    json_safe,
    open_journal,
    write_csv,
)
from wholehand.trials.trial import TrialSpec, run_trial

log = logging.getLogger(__name__)


def _trial(job: TrialJob) -> dict[str, Any]:
    spec = job.spec
    record = run_trial(spec, hand=model("hand", spec.hand), obj=model("object", spec.object))
    return record_row(record)


JOB_KINDS: dict[str, Callable[[TrialJob], dict[str, Any]]] = {
    "trial": _trial,
    "net_force": net_force_row,
    "episode": episode_row,
    "load_test": load_test_row,
    "grasp_generation": generation_row,
}
"""Job kind -> function computing its outcome columns (studies add their measurements)."""


def run_job(job: TrialJob) -> dict[str, Any]:
    """One CSV row: index, labels, spec columns, outcome. An unexpected error becomes a failed
    row whose ``error`` column holds it (one broken trial does not lose a study)."""
    started = time.perf_counter()
    try:
        outcome = JOB_KINDS[job.kind](job)
    except Exception as err:  # noqa: BLE001 - reported in the row and the log
        log.warning("trial %d (%s) failed: %r", job.index, job.labels, err)
        outcome = {"held": False, "failure_stage": "error", "error": f"{type(err).__name__}: {err}"}
        outcome["wall_time_s"] = time.perf_counter() - started
    row: dict[str, Any] = {"index": job.index, "kind": job.kind, **job.labels}
    row.update(spec_columns(job.spec))
    row.update(outcome)
    return row


WITHOUT_ESTIMATOR = frozenset({"grasp_generation"})
"""Job kinds that run no contact estimator (nothing to build for them before the pool)."""


def run_trials(
    specs: Sequence[TrialSpec],
    workers: int | None = None,
    executor: str = "process",
    progress: bool = False,
) -> list[dict[str, Any]]:
    """Run trials as a study runs them: one row per spec, in the order of ``specs``, with the
    spec's columns and the outcome's (``held``, ``failure_stage``, ``contacts_mean``, ...,
    ``error`` for a trial that raised or diverged; see :func:`~wholehand.studies.rows.
    record_row`). ``executor`` is ``"process"`` (``workers`` processes, default one per core),
    ``"serial"`` or ``"ray"``."""
    jobs = [TrialJob(i, spec) for i, spec in enumerate(specs)]
    return execute(jobs, run_job, executor=executor, workers=workers, progress=progress)


def _warm_caches(jobs: list[TrialJob]) -> None:
    """Build each (hand, object, estimator) once here so that workers only read the disk cache."""
    seen = set()
    for job in jobs:
        if job.kind in WITHOUT_ESTIMATOR:
            continue
        s = job.spec
        key = (s.hand, s.object, s.estimator, json.dumps(s.estimator_params, sort_keys=True))
        if key in seen:
            continue
        seen.add(key)
        hand, obj = model("hand", s.hand), model("object", s.object)
        registry.load("contact_estimators", s.estimator, hand=hand, obj=obj, **s.estimator_params)


@dataclass(frozen=True)
class StudyResult:
    """Where a study wrote its results, and what it found."""

    rows: list[dict[str, Any]]
    """Finished rows, sorted by index (all jobs' if the run is complete)."""
    summary: dict[str, Any]
    csv_path: Path
    summary_path: Path
    plot_path: Path
    interrupted: bool = False
    """The run was stopped by ``KeyboardInterrupt`` (its outputs are partial)."""

    @property
    def complete(self) -> bool:
        """Every job of the study has a row."""
        return bool(self.summary.get("complete", True))

    @property
    def journal_path(self) -> Path:
        """The folder's journal, ``rows.jsonl``."""
        return self.csv_path.parent / JOURNAL_NAME


class _Termination:
    """SIGTERM handling of a study run: see :func:`_terminate_as_interrupt`."""

    def __init__(self) -> None:
        self.interrupts = True

    def __call__(self, signum: int, frame: Any) -> None:
        if not self.interrupts:  # stopping or writing: a SIGTERM must not break that off
            print("study: already finishing; writing the finished rows", file=sys.stderr)
            return
        self.interrupts = False
        raise KeyboardInterrupt(f"signal {signum}")


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[_Termination]:
    """While the block runs, SIGTERM (a batch scheduler's stop, ``timeout``, ``kill``) raises
    ``KeyboardInterrupt`` like Ctrl-C, once, so the finished rows are written and the run can be
    resumed. Later SIGTERMs, and any after ``termination.interrupts = False`` (set when the
    outputs are being written), are ignored: they would break off the pool's shutdown (leaving
    the process waiting on its threads) or the writes. Only the main thread can set signal
    handlers; elsewhere nothing changes."""
    termination = _Termination()
    if threading.current_thread() is not threading.main_thread():
        yield termination
        return
    previous = signal.signal(signal.SIGTERM, termination)
    try:
        yield termination
    finally:
        signal.signal(signal.SIGTERM, previous)


def study_jobs(
    study: Study,
    size: str,
    seed: int,
    hand: str = DEFAULT_HAND,
    methods: tuple[str, ...] | None = None,
    grasps: str | Path | None = None,
    only: dict[str, tuple[str, ...]] | None = None,
) -> list[TrialJob]:
    """The jobs of ``study`` on ``hand``, with ``methods`` in place of its own (if given), on
    the grasps of the folder ``grasps`` (if given, :func:`~wholehand.studies.base.
    with_grasps`), those matching ``only`` (if given, :func:`~wholehand.studies.base.
    only_jobs`).

    Raises:
        ConfigError: the design has no trial on this hand (its trials run the hand's stored
            grasps of the study's objects, and there are none).
    """
    # With a grasp folder the design expands over its grasps, not the hand's stored ones.
    with contextlib.nullcontext() if grasps is None else grasps_from(grasps):
        jobs = study.jobs(size, seed, hand)
    if not jobs:
        where = "stored grasps" if grasps is None else f"grasps in {grasps}"
        raise ConfigError(
            f"study {study.name} ({size}) has no trial for hand {hand!r}: it has no {where} of "
            f"the study's objects; generate them with `wholehand grasps generate --hand {hand}`"
            + ("" if grasps is None else f" --out {grasps}")
        )
    jobs = jobs if methods is None else with_methods(jobs, tuple(methods))
    jobs = jobs if grasps is None else with_grasps(jobs, grasps)
    return jobs if not only else only_jobs(jobs, only)


def _output_folder(
    study: Study, out: str | Path | None, hand: str, grasps: str | Path | None
) -> Path:
    """``out`` (created), or ``out/study-<name>[-<hand>][-<grasps>]``."""
    default = f"study-{study.name}" + ("" if hand == DEFAULT_HAND else f"-{Path(hand).name}")
    default += "" if grasps is None else f"-{Path(grasps).name}"
    folder = Path(out) if out is not None else Path("out") / default
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _resumed_rows(
    study: Study, folder: Path, jobs: list[TrialJob], done: dict[int, dict[str, Any]]
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Put the rows of ``folder`` that finish ``jobs`` into ``done`` (by job index) and say so
    on stderr; the rows read from trials.csv and from the journal."""
    cut: list[int] = []
    from_csv, from_journal = folder_rows(folder, cut)
    matched = match_rows(jobs, from_csv + from_journal)
    done.update(matched.rows)
    damaged = matched.n_damaged + len(cut)
    where = f" (trials.csv lines cut short: {cut})" if cut else ""
    print(
        f"study {study.name}: resuming in {folder}: {len(done)} of {len(jobs)} trials "
        f"reused, {matched.n_failed} rows of trials that raised re-run, "
        f"{damaged} damaged rows (no result) re-run{where}, "
        f"{matched.n_ignored} rows matching no job of this design ignored",
        file=sys.stderr,
    )
    return from_csv, from_journal


def _journal_csv_rows(
    journal: IO[str], from_csv: list[dict[str, Any]], from_journal: list[dict[str, Any]]
) -> None:
    """Write the finished rows of trials.csv that the journal lacks to the journal."""
    if not from_csv:
        return
    in_journal = {content_key(r) for r in from_journal}
    for row in from_csv:
        key = content_key(row)
        if not failed_to_run(row) and has_result(row) and key not in in_journal:
            in_journal.add(key)
            journal.write(journal_line(row))
    journal.flush()


def run_study(
    study: Study,
    size: str = "full",
    out: str | Path | None = None,
    workers: int | None = None,
    executor: str = "process",
    seed: int = 0,
    progress: bool = True,
    address: str | None = None,
    resume: bool = False,
    limit: int | None = None,
    hand: str = DEFAULT_HAND,
    methods: tuple[str, ...] | None = None,
    grasps: str | Path | None = None,
    only: dict[str, tuple[str, ...]] | None = None,
) -> StudyResult:
    """Run the jobs of ``study`` and write ``trials.csv``, ``summary.json`` and ``<name>.png``.

    Each finished row is appended at once to the journal ``<out>/rows.jsonl`` (started afresh
    unless ``resume``). Jobs are submitted in :func:`execution_order`. If the run ends with
    jobs missing (``limit``, or ``KeyboardInterrupt``: the pool is shut down, pending jobs are
    cancelled), the outputs hold the finished rows, ``summary.json`` says ``"complete": false``
    with ``n_planned`` and ``n_trials``, and the command that continues the run is printed on
    stderr.

    Args:
        study: the study.
        size: ``"tiny"``, ``"quick"`` or ``"full"``.
        out: output folder (created); default ``out/study-<name>``.
        workers: process-pool size; default one per core.
        executor: ``"process"``, ``"serial"`` or ``"ray"``.
        seed: study seed (random pull axes etc.).
        progress: show a progress bar.
        address: Ray cluster address for ``executor="ray"`` (None: a local instance).
        resume: first reuse the rows already in ``out`` (``rows.jsonl`` and ``trials.csv``,
            matched to the jobs by content, :func:`match_rows`); run only the others.
        limit: run at most this many unfinished jobs this time (None: all of them).
        hand: the hand (a shipped hand's name or a hand folder); the design's grasps that it
            has stored are run.
        methods: allocators replacing the study's methods (:func:`~wholehand.studies.base.
            with_methods`); None: the study's own.
        grasps: a folder of ``<object>.json`` grasp files to run instead of the hand's
            stored grasps (:func:`~wholehand.studies.base.with_grasps`); None: the stored ones.
        only: run only the trials whose labels or spec columns take one of the given values
            per key (:func:`~wholehand.studies.base.only_jobs`), e.g. ``{"theta_deg":
            ("90",)}``; None: all of them.

    Raises:
        ConfigError: an unknown size or executor, ``workers < 1`` or ``limit < 0``.
    """
    size = study.check_size(size)
    if limit is not None and int(limit) < 0:
        raise ConfigError(
            f"limit must be >= 0 (trials to run this time), got {limit}; "
            "pass None to run every unfinished trial"
        )
    jobs = study_jobs(study, size, seed, hand, methods, grasps, only)
    folder = _output_folder(study, out, hand, grasps)
    with study_folder_lock(folder):
        done: dict[int, dict[str, Any]] = {}
        from_csv: list[dict[str, Any]] = []
        from_journal: list[dict[str, Any]] = []
        if resume:
            from_csv, from_journal = _resumed_rows(study, folder, jobs, done)
        n_reused = len(done)
        todo = [job for job in execution_order(jobs) if job.index not in done]
        if limit is not None:
            todo = todo[: int(limit)]
        journal = open_journal(folder / JOURNAL_NAME, fresh=not resume)
        # Keep every row of trials.csv in the journal: trials.csv is rewritten below.
        _journal_csv_rows(journal, from_csv, from_journal)
        started = time.perf_counter()
        made_by = provenance()  # the code the trials run: a commit made meanwhile is not theirs
        with _terminate_as_interrupt() as termination:
            interrupted = _run_journaled(
                study.name, todo, journal, done, termination, executor, workers, progress, address
            )
            rows = [done[i] for i in sorted(done)]
            summary = {
                "study": study.name,
                "provenance": made_by,
                "description": study.description,
                "hand": str(hand),
                "grasps": "stored" if grasps is None else str(grasps),
                "only": {k: list(v) for k, v in (only or {}).items()},
                "size": size,
                "seed": seed,
                "complete": len(rows) == len(jobs),
                "n_planned": len(jobs),
                "n_trials": len(rows),
                "n_reused": n_reused,
                "n_errors": sum(1 for r in rows if r.get("error")),
                "executor": executor,
                "wall_time_s": time.perf_counter() - started,
                **study.summarise(rows),
            }
            result = _write_outputs(study, rows, summary, folder, interrupted)
            if not summary["complete"]:
                why = "interrupted" if interrupted else f"limit {limit}"
                print(
                    f"study {study.name}: {len(rows)} of {len(jobs)} trials finished ({why}); "
                    f"partial results in {folder}. Continue with:\n"
                    f"  {continue_command(study, folder, size, seed, hand, methods, grasps, only)}",
                    file=sys.stderr,
                )
            return result


def _run_journaled(
    name: str,
    todo: list[TrialJob],
    journal: IO[str],
    done: dict[int, dict[str, Any]],
    termination: _Termination,
    executor: str,
    workers: int | None,
    progress: bool,
    address: str | None,
) -> bool:
    """Run ``todo``, writing each finished row to ``journal`` at once and into ``done`` (by
    job index); then close the journal. True when Ctrl-C or SIGTERM interrupted the run."""

    def finished(index: int, row: dict[str, Any]) -> None:
        journal.write(journal_line(row))
        journal.flush()
        done[index] = row

    try:
        if todo:
            _warm_caches(todo)
            execute(
                todo,
                run_job,
                executor=executor,
                workers=workers,
                progress=progress,
                desc=f"study {name}",
                address=address,
                on_result=finished,
            )
    except KeyboardInterrupt:
        print(f"\nstudy {name}: interrupted; writing the finished rows", file=sys.stderr)
        return True
    finally:
        termination.interrupts = False
        journal.close()
    return False


def _write_outputs(
    study: Study,
    rows: list[dict[str, Any]],
    summary: dict[str, Any],
    folder: Path,
    interrupted: bool,
) -> StudyResult:
    """Write ``trials.csv``, ``summary.json`` and the plot of ``rows`` to ``folder``."""
    csv_path = write_csv(rows, folder / "trials.csv")
    summary_path = folder / "summary.json"
    summary_path.write_text(json.dumps(json_safe(summary), indent=2) + "\n")
    plot_path = folder / f"{study.name}.png"
    # The plot gets NaN, not JSON's None, where a group has no valid trial (more likely in a
    # partial run): a gap in the figure instead of a TypeError.
    study.plot(rows, summary, plot_path)
    return StudyResult(rows, json_safe(summary), csv_path, summary_path, plot_path, interrupted)
