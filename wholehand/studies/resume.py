"""Resuming a study: the rows already in its folder matched to its jobs by content, and the
command line that continues a run."""

from __future__ import annotations

import json
import shlex
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wholehand.studies.base import DEFAULT_HAND, Study, TrialJob
from wholehand.studies.rows import SPEC_COLUMNS, spec_columns
from wholehand.studies.study_files import TIMING_COLUMNS, json_default
from wholehand.trials.trial import TrialSpec


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


RESULT_COLUMNS = ("held",)
"""Result columns every finished row of a trial has."""
RESULT_COLUMNS_OF_KIND = {"grasp_generation": ("grasps",)}
"""Result columns of the rows of job kinds that run no trial."""


def has_result(row: dict[str, Any]) -> bool:
    """The row holds every result column of its kind (:data:`RESULT_COLUMNS_OF_KIND`, else
    :data:`RESULT_COLUMNS`)."""
    columns = RESULT_COLUMNS_OF_KIND.get(str(row.get("kind", "")), RESULT_COLUMNS)
    return all(row.get(c) not in (None, "") for c in columns)


@dataclass(frozen=True)
class Matched:
    """Finished rows of a folder matched to a study's jobs (:func:`match_rows`)."""

    rows: dict[int, dict[str, Any]]
    """Job index -> its row (``index`` set to the job's)."""
    n_ignored: int
    """Rows that match no job of the study (another design, size or seed)."""
    n_failed: int
    """Rows skipped because the trial raised (their jobs run again)."""
    n_damaged: int = 0
    """Rows skipped because they lack a result every row has (:data:`RESULT_COLUMNS`; a
    column removed by hand, a row cut short): their jobs run again."""


def match_rows(jobs: Sequence[TrialJob], rows: Iterable[dict[str, Any]]) -> Matched:
    """Give each job the finished row of the same content (:func:`job_key`), whatever index the
    row had: rows of a narrower design with the same seeds fill the matching jobs of a wider
    one. Rows of trials that raised (:func:`failed_to_run`) and rows without a result
    (:data:`RESULT_COLUMNS`) are not used; later rows win. A spec
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
    n_ignored = n_failed = n_damaged = 0
    for row in rows:
        if failed_to_run(row):
            n_failed += 1
            continue
        if not has_result(row):
            n_damaged += 1
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
    return Matched(matched, n_ignored, n_failed, n_damaged)


def execution_order(jobs: Sequence[TrialJob]) -> list[TrialJob]:
    """Jobs in the order they are submitted: by (``labels["repeat"]`` (0 if absent), index).
    Every grasp, method and angle gets its repeat 0 before any gets a repeat 1, so a run cut
    short is a balanced subset of the design."""
    return sorted(jobs, key=lambda j: (j.labels.get("repeat", 0), j.index))


def content_key(row: dict[str, Any]) -> str:
    """A row's content without its index and timings (None cells dropped): equal for a journal
    row and the same row read back from ``trials.csv``."""
    kept = {k: v for k, v in row.items() if v is not None and k not in ("index", *TIMING_COLUMNS)}
    return json.dumps(kept, sort_keys=True, default=json_default)


def continue_command(
    study: Study,
    folder: Path,
    size: str,
    seed: int,
    hand: str = DEFAULT_HAND,
    methods: tuple[str, ...] | None = None,
    grasps: str | Path | None = None,
    only: dict[str, tuple[str, ...]] | None = None,
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
    if grasps is not None:
        words += ["--grasps", str(grasps)]
    for key, values in (only or {}).items():
        for value in values:
            words += ["--only", f"{key}={value}"]
    return shlex.join(words)
