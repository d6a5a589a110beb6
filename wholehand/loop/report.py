"""What a run of the control loop did (:class:`LoopReport`): cycles, statuses, faults, holds,
overruns, stage errors and the switches between stages."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

MAX_KEPT_ERRORS = 20
"""Stage exceptions kept with their traceback (later ones are counted only)."""


@dataclass(frozen=True)
class StageError:
    """An unexpected exception inside a stage."""

    t: float
    """Backend time of the cycle [s]."""
    stage: str
    error: str
    """``Type: message``."""
    traceback: str


@dataclass(frozen=True)
class Transition:
    """A switch between stages."""

    t: float
    """Backend time of the cycle that asked for it [s]."""
    source: str
    target: str
    reason: str


@dataclass(frozen=True)
class Note:
    """Something a stage said without switching (a replan, no plan to reach for), with why."""

    t: float
    """Backend time of the cycle [s]."""
    stage: str
    status: str
    reason: str


@dataclass
class LoopReport:
    """What a run of the loop did, for records and the CLI."""

    cycles: int = 0
    stopped_by: str = ""
    """``"duration"``, ``"end"`` (a stage ended the run) or the observer's reason."""
    status_counts: Counter[str] = field(default_factory=Counter)
    """Cycles per status."""
    faults: Counter[str] = field(default_factory=Counter)
    """Faulted cycles per loop status (``bad_state``, ``stage_error``, ``no_pose``)."""
    last_fault: str = ""
    """Reason of the latest faulted cycle."""
    clamped: int = 0
    """Cycles whose commanded torque exceeded a joint's limit and was clamped to it."""
    max_excess: float = 0.0
    """Largest excess over a limit before clamping [N*m]."""
    held_commands: int = 0
    """Cycles whose stage gave no command, so that the last feasible one stayed applied: faults,
    allocations without a torque (deadline, infeasible, ...) and holds by design (a stage that
    allocates once per object pose)."""
    longest_hold: int = 0
    """Most consecutive held cycles: how long the applied command once went without renewal."""
    longest_hold_s: float = 0.0
    """The longest hold on the backend's clock [s], from the start of its first cycle to the
    end of its last one's period."""
    longest_hold_at: float = 0.0
    """Backend time of the longest hold's first cycle [s]."""
    longest_hold_status: str = ""
    """Status of the longest hold's first cycle: why it began."""
    overruns: int = 0
    """Cycles that computed past their period (wall-clock backends)."""
    max_overrun: float = 0.0
    """Largest overrun [s]."""
    errors: list[StageError] = field(default_factory=list)
    """Stage exceptions, the first :data:`MAX_KEPT_ERRORS` with their tracebacks."""
    n_errors: int = 0
    """All stage exceptions, kept or not."""
    transitions: list[Transition] = field(default_factory=list)
    """Every switch between stages, in order."""
    notes: list[Note] = field(default_factory=list)
    """What the stages said, with a reason, without switching: each change, in order (a
    reason repeated in the next cycles is kept once)."""

    def as_dict(self) -> dict[str, object]:
        """JSON-serialisable summary (tracebacks of at most three errors)."""
        return {
            "cycles": self.cycles,
            "stopped_by": self.stopped_by,
            "status_counts": dict(self.status_counts),
            "faults": dict(self.faults),
            "last_fault": self.last_fault,
            "clamped": self.clamped,
            "max_excess_Nm": self.max_excess,
            "held_commands": self.held_commands,
            "longest_hold": self.longest_hold,
            "longest_hold_s": self.longest_hold_s,
            "longest_hold_at": self.longest_hold_at,
            "longest_hold_status": self.longest_hold_status,
            "overruns": self.overruns,
            "max_overrun_s": self.max_overrun,
            "n_errors": self.n_errors,
            "errors": [e.__dict__ for e in self.errors[:3]],
            "transitions": [t.__dict__ for t in self.transitions],
            "notes": [n.__dict__ for n in self.notes],
        }
