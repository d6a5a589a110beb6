"""The outcome of a run, defined once: held or lost, where, and what went wrong on the way.

The CLI, the studies and the examples read a run's verdict from :func:`outcome_of` only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wholehand.allocation.base import AllocationStatus, is_balanced
from wholehand.loop.record import RunRecord

DIVERGED_PREFIX = "simulation diverged"
"""Start of the ``error`` of a run whose MuJoCo simulation diverged (the run itself finished)."""


@dataclass(frozen=True)
class RunOutcome:
    """What a run came to."""

    held: bool
    """The grasp held in every cycle and every protocol phase was reached."""
    phases_total: int
    phases_reached: int
    failure_phase: str
    """Phase in which the grasp was first lost; ``"incomplete"`` if it never was but the run
    ended before the last phase; ``""`` when held."""
    cycles: int
    final_displacement_mm: float
    """Distance of the object origin at the last cycle from its place at the first [mm]."""
    error: str
    """Why the run says nothing about the controller ("" if it does): the simulation diverged,
    or a stage raised (see ``meta["loop"]["errors"]``)."""
    unbalanced_cycles: int
    """Cycles with a fresh allocation whose forces do not balance the object: status
    ``unbalanced``, and ``ok`` cycles of other allocators (or older records) whose forces are
    not :attr:`~wholehand.allocation.base.Allocation.balanced`."""


def outcome_of(record: RunRecord) -> RunOutcome:
    """The outcome of a recorded run."""
    a = record.arrays()
    n = int(a["t"].size)
    phases = record.phases
    reached = int(a["phase"].max()) + 1 if n else 0
    lost = np.flatnonzero(~a["held"].astype(bool)) if n else np.zeros(0, dtype=int)
    held = bool(n and lost.size == 0 and reached == len(phases))
    failure = ""
    if lost.size:
        failure = phases[int(a["phase"][lost[0]])]
    elif not held:
        failure = "incomplete"
    moved = float(1e3 * np.linalg.norm(a["p_object"][-1] - a["p_object"][0])) if n else np.nan
    ok = np.flatnonzero(a["status"] == AllocationStatus.OK.value) if n else np.zeros(0, int)
    forces = record.rows.get("contact_f", [])
    unbalanced = sum(not is_balanced(a["residual_wrench"][i], forces[i]) for i in ok)
    if n:
        unbalanced += int(np.count_nonzero(a["status"] == AllocationStatus.UNBALANCED.value))
    return RunOutcome(held, len(phases), reached, failure, n, moved, _error(record), unbalanced)


def _error(record: RunRecord) -> str:
    diverged = record.meta.get("sim_warnings", {}).get("bad_qacc", 0)
    if diverged:
        return f"{DIVERGED_PREFIX} (MuJoCo bad_qacc x{diverged})"
    n_errors = record.meta.get("loop", {}).get("n_errors", 0)
    if n_errors:
        first = record.meta["loop"]["errors"][0]["error"]
        return f"stage raised x{n_errors}: {first}"
    return ""


def sim_warnings_error(warnings: dict[str, int]) -> str:
    """A row's ``error`` for a run with these simulator warnings: the warnings behind
    :data:`DIVERGED_PREFIX` when MuJoCo diverged (``bad_qacc`` or ``bad_qpos``), else ""."""
    diverged = warnings.get("bad_qacc", 0) + warnings.get("bad_qpos", 0)
    return f"{DIVERGED_PREFIX}: {warnings}" if diverged else ""
