"""The outcome of a run, defined once: held or lost, where, and what went wrong on the way.

The CLI, the studies and the examples read a run's verdict from :func:`outcome_of` only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wholehand.allocation.base import AllocationStatus, is_balanced
from wholehand.loop.record import RunRecord
from wholehand.models.poses import rotation_angle

DIVERGED_PREFIX = "simulation diverged"
"""Start of the ``error`` of a run whose MuJoCo simulation diverged (the run itself finished)."""

STRICT_SLIP_MM = 20.0
"""The strict criterion's bound on how far the object may end from where the hand held it once
the grasp settled, in the hand base's frame [mm]."""
STRICT_SLIP_DEG = 20.0
"""The strict criterion's bound on how far the object may end turned from how the hand held it
once the grasp settled [deg]."""


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
    slip_mm: float = float("nan")
    """How far the object ended from where the hand held it once the grasp settled (the end of
    the first phase): its origin's displacement in the hand base's frame to the last cycle
    [mm] (NaN without the base's pose in the record)."""
    slip_deg: float = float("nan")
    """How far the object ended turned in the hand base's frame [deg]."""

    @property
    def held_strict(self) -> bool:
        """The strict criterion, beside the paper's: :attr:`held`, and the object ended within
        :data:`STRICT_SLIP_MM` and :data:`STRICT_SLIP_DEG` of where and how the hand held it
        once the grasp settled. The paper's hull criterion calls a bottle that slid 7 cm
        through the hand held; this one does not."""
        return self.held and self.slip_mm <= STRICT_SLIP_MM and self.slip_deg <= STRICT_SLIP_DEG


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
    slip_mm, slip_deg = _slip(a) if n else (np.nan, np.nan)
    return RunOutcome(
        held, len(phases), reached, failure, n, moved, _error(record), unbalanced, slip_mm, slip_deg
    )


def _slip(a: dict[str, np.ndarray]) -> tuple[float, float]:
    """The object's displacement [mm] and turn [deg] in the hand base's frame, from the end of
    the first phase to the last cycle (NaN without the base's pose)."""
    shape = a["p_object"].shape
    if not (a["p_base"].shape == a["r_base"].shape == shape and np.isfinite(a["p_base"]).all()):
        return np.nan, np.nan  # a record without the base's pose

    def in_base(i: int) -> tuple[np.ndarray, np.ndarray]:
        R_base = pin.exp3(a["r_base"][i])
        R_object = pin.exp3(a["r_object"][i])
        return R_base.T @ (a["p_object"][i] - a["p_base"][i]), R_base.T @ R_object

    # Where the hand holds it: at the end of the first phase (the grasp settled), or the
    # first cycle of a run with one phase.
    later = np.flatnonzero(a["phase"] > a["phase"][0])
    p0, R0 = in_base(int(later[0]) - 1 if later.size else 0)
    p1, R1 = in_base(-1)
    return float(1e3 * np.linalg.norm(p1 - p0)), float(np.degrees(rotation_angle(R0, R1)))


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
