"""Run a study: expand its jobs, execute them, write ``trials.csv``, ``summary.json`` and a PNG.

Every row of ``trials.csv`` is one trial, sorted by its index in the study. Its columns are the
study's labels, every :class:`~wholehand.loop.trial.TrialSpec` field, the outcome (held, stages
reached, failure stage, contact counts, final object displacement) and, last, the wall-clock
timings listed in :data:`TIMING_COLUMNS`. Everything but the timings is a function of the study,
its size and its seed: the same seed gives the same rows whatever the executor or worker count.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from wholehand import registry
from wholehand.allocation.base import AllocationStatus
from wholehand.loop.record import STATUS_CODES, RunRecord
from wholehand.loop.trial import TrialSpec, run_trial
from wholehand.studies.base import Study, TrialJob
from wholehand.studies.executors import execute

log = logging.getLogger(__name__)

TIMING_COLUMNS = ("wall_time_s", "qp_p50_us", "cycle_mean_us", "control_rate_hz")
"""Wall-clock columns of ``trials.csv``: they vary from run to run (not part of determinism)."""

SPEC_COLUMNS = tuple(TrialSpec.__dataclass_fields__)
"""TrialSpec fields, one column each (parameter dicts as JSON)."""

_MODELS: dict[tuple[str, str], Any] = {}
"""Per-process cache of loaded hands and objects (worker processes run many trials)."""


def _model(kind: str, name: str) -> Any:
    key = (kind, name)
    if key not in _MODELS:
        if kind == "hand":
            from wholehand.models.hand import load_hand

            _MODELS[key] = load_hand(name)
        else:
            from wholehand.models.objects import load_object

            _MODELS[key] = load_object(name)
    return _MODELS[key]


def spec_columns(spec: TrialSpec) -> dict[str, Any]:
    """The spec as CSV cells: names for classes, sorted JSON for parameter dicts."""
    out: dict[str, Any] = {}
    for name in SPEC_COLUMNS:
        value = getattr(spec, name)
        if isinstance(value, dict):
            value = json.dumps(value, sort_keys=True, default=str)
        elif isinstance(value, type):
            value = value.__name__
        out[name] = value
    return out


def record_row(record: RunRecord) -> dict[str, Any]:
    """Outcome and timing columns of one run record."""
    a = record.arrays()
    n = int(a["t"].size)
    stages = record.stages
    reached = int(a["stage"].max()) + 1 if n else 0
    lost = np.flatnonzero(~a["held"].astype(bool)) if n else np.zeros(0, dtype=int)
    held = bool(n and lost.size == 0 and reached == len(stages))
    failure = ""
    if lost.size:
        failure = stages[int(a["stage"][lost[0]])]
    elif not held:
        failure = "incomplete"
    status = a["status"]
    hold_code = STATUS_CODES[AllocationStatus.HOLD]
    ok_code = STATUS_CODES[AllocationStatus.OK]
    p0 = a["p_object"][0] if n else np.zeros(3)
    cycle = a["cycle_time"]
    return {
        "held": held,
        "stages_total": len(stages),
        "stages_reached": reached,
        "failure_stage": failure,
        "cycles": n,
        "contacts_mean": round(float(a["n_contacts"].mean()), 6) if n else float("nan"),
        "n_contacts_gt_init": record.meta.get("n_contacts_gt_init"),
        "ok_fraction": round(float(np.mean(status == ok_code)), 6) if n else float("nan"),
        "hold_fraction": round(float(np.mean(status == hold_code)), 6) if n else float("nan"),
        "final_displacement_mm": round(float(1e3 * np.linalg.norm(a["p_object"][-1] - p0)), 6)
        if n
        else float("nan"),
        "error": _simulation_error(record),
        "wall_time_s": float(record.meta.get("wall_time_s", float("nan"))),
        "qp_p50_us": float(np.percentile(a["qp_time"], 50) * 1e6) if n else float("nan"),
        "cycle_mean_us": float(cycle.mean() * 1e6) if n else float("nan"),
        "control_rate_hz": float(1.0 / cycle.mean()) if n and cycle.mean() > 0 else float("nan"),
    }


def _simulation_error(record: RunRecord) -> str:
    """Why a trial says nothing about the controller ("" if it does): the simulation diverged."""
    diverged = record.meta.get("sim_warnings", {}).get("bad_qacc", 0)
    return f"simulation diverged (MuJoCo bad_qacc x{diverged})" if diverged else ""


def _trial(job: TrialJob) -> dict[str, Any]:
    spec = job.spec
    record = run_trial(spec, hand=_model("hand", spec.hand), obj=_model("object", spec.object))
    return record_row(record)


JOB_KINDS: dict[str, Callable[[TrialJob], dict[str, Any]]] = {"trial": _trial}
"""Job kind -> function computing its outcome columns (studies add their measurements)."""


def run_job(job: TrialJob) -> dict[str, Any]:
    """One CSV row: index, labels, spec columns, outcome. An unexpected error becomes a failed
    row whose ``error`` column holds it (one broken trial does not lose a study)."""
    _register_kinds()
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


def _register_kinds() -> None:
    if "net_force" not in JOB_KINDS:
        from wholehand.studies.consistency import net_force_row

        JOB_KINDS["net_force"] = net_force_row


def _warm_caches(jobs: list[TrialJob]) -> None:
    """Build each (hand, object, estimator) once here so that workers only read the disk cache."""
    seen = set()
    for job in jobs:
        s = job.spec
        key = (s.hand, s.object, s.estimator, json.dumps(s.estimator_params, sort_keys=True))
        if key in seen:
            continue
        seen.add(key)
        hand, obj = _model("hand", s.hand), _model("object", s.object)
        registry.load("contact_estimators", s.estimator, hand=hand, obj=obj, **s.estimator_params)


@dataclass(frozen=True)
class StudyResult:
    """Where a study wrote its results, and what it found."""

    rows: list[dict[str, Any]]
    summary: dict[str, Any]
    csv_path: Path
    summary_path: Path
    plot_path: Path


def columns_of(rows: list[dict[str, Any]]) -> list[str]:
    """CSV header: every key in first-seen order, timing columns last."""
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    return [c for c in cols if c not in TIMING_COLUMNS] + [c for c in TIMING_COLUMNS if c in cols]


def write_csv(rows: list[dict[str, Any]], path: Path) -> Path:
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns_of(rows), restval="")
        writer.writeheader()
        for r in rows:
            writer.writerow({k: ("" if v is None else v) for k, v in r.items()})
    return path


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


def run_study(
    study: Study,
    size: str = "full",
    out: str | Path | None = None,
    workers: int | None = None,
    executor: str = "process",
    seed: int = 0,
    progress: bool = True,
    address: str | None = None,
) -> StudyResult:
    """Run every job of ``study`` and write ``trials.csv``, ``summary.json`` and ``<name>.png``.

    Args:
        study: the study.
        size: ``"tiny"``, ``"quick"`` or ``"full"``.
        out: output folder (created); default ``out/study-<name>``.
        workers: process-pool size; default one per core.
        executor: ``"process"``, ``"serial"`` or ``"ray"``.
        seed: study seed (random pull axes etc.).
        address: Ray cluster address for ``executor="ray"`` (None: a local instance).
        progress: show a progress bar.
    """
    size = study.check_size(size)
    folder = Path(out) if out is not None else Path("out") / f"study-{study.name}"
    folder.mkdir(parents=True, exist_ok=True)
    jobs = study.jobs(size, seed)
    started = time.perf_counter()
    _warm_caches(jobs)
    rows = execute(
        jobs,
        run_job,
        executor=executor,
        workers=workers,
        progress=progress,
        desc=f"study {study.name}",
        address=address,
    )
    wall = time.perf_counter() - started
    summary = {
        "study": study.name,
        "description": study.description,
        "size": size,
        "seed": seed,
        "n_trials": len(rows),
        "n_errors": sum(1 for r in rows if r.get("error")),
        "executor": executor,
        "wall_time_s": wall,
        **study.summarise(rows),
    }
    summary = _json_safe(summary)
    csv_path = write_csv(rows, folder / "trials.csv")
    summary_path = folder / "summary.json"
    summary_path.write_text(json.dumps(summary, indent=2) + "\n")
    plot_path = folder / f"{study.name}.png"
    import matplotlib

    matplotlib.use("Agg")
    study.plot(rows, summary, plot_path)
    return StudyResult(rows, summary, csv_path, summary_path, plot_path)
