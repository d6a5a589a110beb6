"""One trial's row of a study: the spec's columns and the outcome columns of its run record."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from wholehand.allocation.base import AllocationStatus
from wholehand.loop.record import RunRecord
from wholehand.trials.outcome import outcome_of
from wholehand.trials.trial import TrialSpec

SPEC_COLUMNS = tuple(TrialSpec.__dataclass_fields__)
"""TrialSpec fields, one column each (parameter dicts as JSON)."""


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
    """Outcome and timing columns of one run record (:func:`~wholehand.trials.outcome.outcome_of`).

    The columns keep their names of earlier versions (``stages_total``, ``failure_stage``: the
    protocol's phases), so committed study rows and ``--resume`` stay valid. A run in which a
    stage raised gets ``failure_stage == "error"``: it is no result and is re-run on resume.
    """
    outcome = outcome_of(record)
    a = record.arrays()
    n = outcome.cycles
    status = a["status"]
    cycle = a["cycle_time"]
    stage_raised = bool(record.meta.get("loop", {}).get("n_errors", 0))
    return {
        "held": outcome.held,
        "held_strict": outcome.held_strict,
        "slip_mm": round(outcome.slip_mm, 3),
        "slip_deg": round(outcome.slip_deg, 3),
        "stages_total": outcome.phases_total,
        "stages_reached": outcome.phases_reached,
        "failure_stage": "error" if stage_raised else outcome.failure_phase,
        "cycles": n,
        "contacts_mean": round(float(a["n_contacts"].mean()), 6) if n else float("nan"),
        "n_contacts_gt_init": record.meta.get("n_contacts_gt_init"),
        "ok_fraction": round(float(np.mean(status == AllocationStatus.OK.value)), 6)
        if n
        else float("nan"),
        "unbalanced_fraction": round(float(np.mean(status == AllocationStatus.UNBALANCED.value)), 6)
        if n
        else float("nan"),
        "hold_fraction": round(float(np.mean(status == AllocationStatus.HOLD.value)), 6)
        if n
        else float("nan"),
        "final_displacement_mm": round(outcome.final_displacement_mm, 6) if n else float("nan"),
        "error": outcome.error,
        "wall_time_s": float(record.meta.get("wall_time_s", float("nan"))),
        "qp_p50_us": float(np.percentile(a["qp_time"], 50) * 1e6) if n else float("nan"),
        "cycle_mean_us": float(cycle.mean() * 1e6) if n else float("nan"),
        "cycle_p99_us": float(np.percentile(cycle, 99) * 1e6) if n else float("nan"),
        "cycle_max_us": float(cycle.max() * 1e6) if n else float("nan"),
        "control_rate_hz": float(1.0 / cycle.mean()) if n and cycle.mean() > 0 else float("nan"),
    }
