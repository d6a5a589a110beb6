"""Run a study: expand its jobs, execute them, write ``trials.csv``, ``summary.json`` and a PNG.

Every row of ``trials.csv`` is one trial, sorted by its index in the study. Its columns are the
study's labels, every :class:`~wholehand.loop.trial.TrialSpec` field, the outcome (held, stages
reached, failure stage, contact counts, final object displacement) and, last, the wall-clock
timings listed in :data:`TIMING_COLUMNS`. Everything but the timings is a function of the study,
its size and its seed: the same seed gives the same rows whatever the executor or worker count.

Long runs: while a study runs, every finished row is appended to the journal ``rows.jsonl``
(:data:`JOURNAL_NAME`, one JSON object a line, flushed per row). ``run_study(..., resume=True)``
reads the rows already in the folder (journal and ``trials.csv``), matches them to the study's
jobs by content (:func:`match_rows`) and runs only the rest; ``limit`` caps the trials run this
time. A run that ends with trials missing still writes its outputs, marked ``"complete": false``.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import logging
import math
import os
import re
import shlex
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from wholehand import registry
from wholehand.errors import ConfigError
from wholehand.loop.trial import TrialSpec, run_trial
from wholehand.studies.base import DEFAULT_HAND, Study, TrialJob, with_methods
from wholehand.studies.consistency import net_force_row
from wholehand.studies.executors import execute
from wholehand.studies.models import model
from wholehand.studies.reach import episode_row
from wholehand.studies.rows import SPEC_COLUMNS, record_row, spec_columns

log = logging.getLogger(__name__)

TIMING_COLUMNS = ("wall_time_s", "qp_p50_us", "cycle_mean_us", "control_rate_hz")
"""Wall-clock columns of ``trials.csv``: they vary from run to run (not part of determinism)."""

TEXT_COLUMNS = ("kind", "failure_stage", "error") + tuple(
    f.name
    for f in dataclasses.fields(TrialSpec)
    if isinstance(f.default, str) or f.default_factory is dict
)
"""Columns :func:`read_csv` keeps as strings, an empty cell included (``""``, not None): the
job kind, the failure stage, the error and the spec's names and JSON parameter dicts."""

JOURNAL_NAME = "rows.jsonl"
"""Journal of a study folder: every finished row as one JSON line, appended as it arrives."""


def _trial(job: TrialJob) -> dict[str, Any]:
    spec = job.spec
    record = run_trial(spec, hand=model("hand", spec.hand), obj=model("object", spec.object))
    return record_row(record)


JOB_KINDS: dict[str, Callable[[TrialJob], dict[str, Any]]] = {
    "trial": _trial,
    "net_force": net_force_row,
    "episode": episode_row,
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


def _warm_caches(jobs: list[TrialJob]) -> None:
    """Build each (hand, object, estimator) once here so that workers only read the disk cache."""
    seen = set()
    for job in jobs:
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


def columns_of(rows: list[dict[str, Any]]) -> list[str]:
    """CSV header: every key in first-seen order, timing columns last."""
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    return [c for c in cols if c not in TIMING_COLUMNS] + [c for c in TIMING_COLUMNS if c in cols]


def write_csv(rows: list[dict[str, Any]], path: str | Path) -> Path:
    """Write ``rows`` as CSV (header :func:`columns_of`, None as an empty cell); read it back
    with :func:`read_csv`. The file is replaced at once (written aside, then renamed), so an
    interruption never leaves half a ``trials.csv``."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns_of(rows), restval="")
        writer.writeheader()
        for r in rows:
            writer.writerow({k: ("" if v is None else v) for k, v in r.items()})
    os.replace(tmp, path)
    return path


_INT = re.compile(r"[-+]?(0|[1-9][0-9]*)")
"""An int as ``str(int)`` writes it (no leading zeros: ``"077"`` stays a string)."""
_FLOAT = re.compile(
    r"[-+]?(([0-9]+\.[0-9]*|\.[0-9]+)([eE][-+]?[0-9]+)?|[0-9]+[eE][-+]?[0-9]+|nan|inf)"
)
"""A float as ``str(float)`` writes it: with a point or an exponent, or nan / inf."""


def _cell(text: str) -> Any:
    """A CSV cell written by :func:`write_csv` as the Python value it came from."""
    if text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    if _INT.fullmatch(text):
        return int(text)
    if _FLOAT.fullmatch(text):
        return float(text)
    return text


def read_csv(path: str | Path) -> list[dict[str, Any]]:
    """Rows of a CSV written by :func:`write_csv`, typed back: ``True``/``False`` as booleans,
    integers (no leading zeros) as int, numbers with a point or an exponent, ``nan`` and
    ``inf`` as float, an empty cell as None, anything else as a string. :data:`TEXT_COLUMNS`
    always stay strings (``""`` included), so the spec's JSON parameter dicts compare equal to
    :func:`spec_columns`.

    Raises:
        ConfigError: a line has more cells than the header has columns.
    """
    path = Path(path)
    rows: list[dict[str, Any]] = []
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        for raw in reader:
            if None in raw:
                raise ConfigError(
                    f"{path}, line {reader.line_num}: more cells than the header's "
                    f"{len(reader.fieldnames or ())} columns; the file is not a trials.csv "
                    "written by wholehand (remove it, or the line, to go on)"
                )
            rows.append({k: (v if k in TEXT_COLUMNS else _cell(v or "")) for k, v in raw.items()})
    return rows


def read_journal(path: str | Path) -> list[dict[str, Any]]:
    """Rows of a journal (:data:`JOURNAL_NAME`), in the order they were appended. A line that is
    not a JSON object (e.g. cut short when the run was killed) is skipped with a warning."""
    path = Path(path)
    rows: list[dict[str, Any]] = []
    with open(path, encoding="utf-8") as fh:
        for number, line in enumerate(fh, start=1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                row = None
            if not isinstance(row, dict):
                log.warning("%s, line %d: not a JSON row (cut short?); skipped", path, number)
                continue
            rows.append(row)
    return rows


def _folder_rows(folder: Path) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """(rows of ``trials.csv``, rows of the journal) of a folder, each empty if absent."""
    csv_path, journal_path = folder / "trials.csv", folder / JOURNAL_NAME
    from_csv = read_csv(csv_path) if csv_path.exists() else []
    from_journal = read_journal(journal_path) if journal_path.exists() else []
    return from_csv, from_journal


def _key(kind: Any, labels: dict[str, Any], spec: Iterable[Any]) -> str:
    return json.dumps([kind, labels, list(spec)], sort_keys=True, default=str)


def job_key(job: TrialJob) -> str:
    """What identifies a job's row by content: (kind, labels, spec columns) as a JSON string.
    The spec holds the seed, the protocol and every parameter, not the job's index."""
    return _key(job.kind, job.labels, spec_columns(job.spec).values())


def failed_to_run(row: dict[str, Any]) -> bool:
    """The trial raised (``failure_stage == "error"``): its row is no result and is re-run.
    A diverged simulation is a result (deterministic) and is kept."""
    return row.get("failure_stage") == "error"


@dataclass(frozen=True)
class Matched:
    """Finished rows of a folder matched to a study's jobs (:func:`match_rows`)."""

    rows: dict[int, dict[str, Any]]
    """Job index -> its row (``index`` set to the job's)."""
    n_ignored: int
    """Rows that match no job of the study (another design, size or seed)."""
    n_failed: int
    """Rows skipped because the trial raised (their jobs run again)."""


def match_rows(jobs: Sequence[TrialJob], rows: Iterable[dict[str, Any]]) -> Matched:
    """Give each job the finished row of the same content (:func:`job_key`), whatever index the
    row had: rows of a narrower design with the same seeds fill the matching jobs of a wider
    one. Rows of trials that raised (:func:`failed_to_run`) are not used; later rows win. A spec
    column a row lacks, or holds empty (written before the field existed: such a row read back
    from a ``trials.csv`` that also holds newer rows has an empty cell there), counts as the
    field's default; no spec field has the empty string as a valid value. A matched row gets
    the job's kind and spec cells, so rows of older versions read back like new ones."""
    by_key: dict[str, list[int]] = {}
    for job in jobs:
        by_key.setdefault(job_key(job), []).append(job.index)
    jobs_by_index = {job.index: job for job in jobs}
    label_sets = list(dict.fromkeys(tuple(job.labels) for job in jobs))
    default = spec_columns(TrialSpec())  # for spec fields a row predates (older versions)
    matched: dict[int, dict[str, Any]] = {}
    n_ignored = n_failed = 0
    for row in rows:
        if failed_to_run(row):
            n_failed += 1
            continue
        spec = [default[c] if row.get(c) in (None, "") else row[c] for c in SPEC_COLUMNS]
        hits: list[int] = []
        for names in label_sets:
            if all(n in row for n in names):
                labels = {n: row[n] for n in names}
                hits += by_key.get(_key(row.get("kind") or "trial", labels, spec), [])
        if not hits:
            n_ignored += 1
        for index in hits:
            job = jobs_by_index[index]
            matched[index] = {**row, "kind": job.kind, **spec_columns(job.spec), "index": index}
    return Matched(matched, n_ignored, n_failed)


def execution_order(jobs: Sequence[TrialJob]) -> list[TrialJob]:
    """Jobs in the order they are submitted: by (``labels["repeat"]`` (0 if absent), index).
    Every grasp, method and angle gets its repeat 0 before any gets a repeat 1, so a run cut
    short is a balanced subset of the design."""
    return sorted(jobs, key=lambda j: (j.labels.get("repeat", 0), j.index))


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    return str(value)


def _journal_line(row: dict[str, Any]) -> str:
    """One journal line: the row as JSON (NaN and inf as Python's json writes them)."""
    return json.dumps(row, default=_json_default) + "\n"


def _content_key(row: dict[str, Any]) -> str:
    """A row's content without its index and timings (None cells dropped): equal for a journal
    row and the same row read back from ``trials.csv``."""
    kept = {k: v for k, v in row.items() if v is not None and k not in ("index", *TIMING_COLUMNS)}
    return json.dumps(kept, sort_keys=True, default=_json_default)


def _open_journal(path: Path, fresh: bool) -> IO[str]:
    """The journal opened for appending (emptied first if ``fresh``); a last line cut short by a
    killed run is ended so that the next row starts on a line of its own."""
    if fresh or not path.exists():
        return open(path, "w", encoding="utf-8")
    cut_short = False
    if path.stat().st_size:
        with open(path, "rb") as raw:
            raw.seek(-1, os.SEEK_END)
            cut_short = raw.read(1) != b"\n"
    fh = open(path, "a", encoding="utf-8")  # closed by run_study
    if cut_short:
        fh.write("\n")
    return fh


def _json_safe(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    if isinstance(value, np.generic):
        return _json_safe(value.item())
    return value


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


def continue_command(
    study: Study,
    folder: Path,
    size: str,
    seed: int,
    hand: str = DEFAULT_HAND,
    methods: tuple[str, ...] | None = None,
) -> str:
    """The command line that continues a study run in ``folder``."""
    words = ["wholehand", "study", study.name, "--out", str(folder), "--resume"]
    if size != "full":
        words += ["--size", size]
    if seed != 0:
        words += ["--seed", str(seed)]
    if hand != DEFAULT_HAND:
        words += ["--hand", hand]
    if methods is not None:
        words += ["--methods", ",".join(methods)]
    return shlex.join(words)


def study_jobs(
    study: Study,
    size: str,
    seed: int,
    hand: str = DEFAULT_HAND,
    methods: tuple[str, ...] | None = None,
) -> list[TrialJob]:
    """The jobs of ``study`` on ``hand``, with ``methods`` in place of its own (if given)."""
    jobs = study.jobs(size, seed, hand)
    return jobs if methods is None else with_methods(jobs, tuple(methods))


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

    Raises:
        ConfigError: an unknown size or executor, ``workers < 1`` or ``limit < 0``.
    """
    size = study.check_size(size)
    if limit is not None and int(limit) < 0:
        raise ConfigError(
            f"limit must be >= 0 (trials to run this time), got {limit}; "
            "pass None to run every unfinished trial"
        )
    jobs = study_jobs(study, size, seed, hand, methods)
    if not jobs:
        raise ConfigError(
            f"study {study.name} ({size}) has no trial for hand {hand!r}: it has no stored "
            "grasps of the study's objects; generate them with `wholehand grasps generate "
            f"--hand {hand}`"
        )
    default = f"study-{study.name}" + ("" if hand == DEFAULT_HAND else f"-{Path(hand).name}")
    folder = Path(out) if out is not None else Path("out") / default
    folder.mkdir(parents=True, exist_ok=True)
    journal_path = folder / JOURNAL_NAME
    done: dict[int, dict[str, Any]] = {}
    from_csv: list[dict[str, Any]] = []
    if resume:
        from_csv, from_journal = _folder_rows(folder)
        matched = match_rows(jobs, from_csv + from_journal)
        done.update(matched.rows)
        print(
            f"study {study.name}: resuming in {folder}: {len(done)} of {len(jobs)} trials "
            f"reused, {matched.n_failed} rows of trials that raised re-run, "
            f"{matched.n_ignored} rows matching no job of this design ignored",
            file=sys.stderr,
        )
    n_reused = len(done)
    todo = [job for job in execution_order(jobs) if job.index not in done]
    if limit is not None:
        todo = todo[: int(limit)]

    journal = _open_journal(journal_path, fresh=not resume)
    if from_csv:  # keep every row of trials.csv in the journal: trials.csv is rewritten below
        in_journal = {_content_key(r) for r in from_journal}
        for row in from_csv:
            key = _content_key(row)
            if not failed_to_run(row) and key not in in_journal:
                in_journal.add(key)
                journal.write(_journal_line(row))
        journal.flush()

    def finished(index: int, row: dict[str, Any]) -> None:
        journal.write(_journal_line(row))
        journal.flush()
        done[index] = row

    started = time.perf_counter()
    interrupted = False
    with _terminate_as_interrupt() as termination:
        try:
            if todo:
                _warm_caches(todo)
                execute(
                    todo,
                    run_job,
                    executor=executor,
                    workers=workers,
                    progress=progress,
                    desc=f"study {study.name}",
                    address=address,
                    on_result=finished,
                )
        except KeyboardInterrupt:
            interrupted = True
            print(f"\nstudy {study.name}: interrupted; writing the finished rows", file=sys.stderr)
        finally:
            termination.interrupts = False
            journal.close()
        wall = time.perf_counter() - started
        rows = [done[i] for i in sorted(done)]
        complete = len(rows) == len(jobs)
        summary = {
            "study": study.name,
            "description": study.description,
            "hand": str(hand),
            "size": size,
            "seed": seed,
            "complete": complete,
            "n_planned": len(jobs),
            "n_trials": len(rows),
            "n_reused": n_reused,
            "n_errors": sum(1 for r in rows if r.get("error")),
            "executor": executor,
            "wall_time_s": wall,
            **study.summarise(rows),
        }
        csv_path = write_csv(rows, folder / "trials.csv")
        summary_path = folder / "summary.json"
        summary_path.write_text(json.dumps(_json_safe(summary), indent=2) + "\n")
        plot_path = folder / f"{study.name}.png"
        import matplotlib

        matplotlib.use("Agg")
        # The plot gets NaN, not JSON's None, where a group has no valid trial (more likely in a
        # partial run): a gap in the figure instead of a TypeError.
        study.plot(rows, summary, plot_path)
        summary = _json_safe(summary)
        if not complete:
            why = "interrupted" if interrupted else f"limit {limit}"
            print(
                f"study {study.name}: {len(rows)} of {len(jobs)} trials finished ({why}); "
                f"partial results in {folder}. Continue with:\n"
                f"  {continue_command(study, folder, size, seed, hand, methods)}",
                file=sys.stderr,
            )
        return StudyResult(rows, summary, csv_path, summary_path, plot_path, interrupted)
