"""What the cycles that ran past their period were doing, to find where a late cycle's time went.

On a wall clock the loop counts an overrun when the wait for a fresh joint state before a cycle
and the cycle itself (its reading, the stage, the command, the observers) take more than the
period (:class:`~wholehand.loop.control_loop.ControlLoop`). :class:`LateCycles` watches the
loop's count and keeps, for each cycle after which it grew, the parts of that cycle's time: the
stage and its status, the contact estimation and the allocation's solve (with the QP solver's
part of it) within the cycle, the joint-state wait before it, the time from its start to the
next cycle's start and the garbage collections that ran meanwhile. The controller's report
carries them as ``late_cycles``.
"""

from __future__ import annotations

import gc
from dataclasses import asdict, dataclass
from typing import Any

from wholehand.loop.control_loop import ControlLoop, Cycle, Observer

MOST_KEPT = 200
"""Late cycles kept in full (the first ones; all are counted)."""


@dataclass(frozen=True)
class LateCycle:
    """One cycle after which the loop counted an overrun. Times in seconds."""

    t: float
    """Backend time at the cycle's start [s]."""
    period_s: float
    """The loop's period."""
    stage: str
    status: str
    cycle_s: float
    """From reading the state to applying the command."""
    estimate_s: float
    """Kinematics and contact estimation, part of ``cycle_s``."""
    solve_s: float
    """The allocation's solve (0 without one), part of ``cycle_s``."""
    solver_s: float
    """The part of ``solve_s`` inside the QP solver's calls."""
    contacts: int
    """Contacts the stage used."""
    joint_wait_s: float
    """Waiting for a fresh joint state before the cycle, within its period."""
    to_next_s: float
    """From the cycle's start to the next one's (a period, were it on time)."""
    collections: int
    """Garbage collections from the end of the cycle before to the start of the next one."""


class LateCycles(Observer):
    """Keeps :class:`LateCycle` records of the cycles after which the loop's overrun count grew
    (at most :data:`MOST_KEPT`; :attr:`count` counts them all). The joint-state wait is read
    from the backend's ``sync_wait`` (0 for a backend without one)."""

    def __init__(self) -> None:
        self.kept: list[LateCycle] = []
        self.count = 0
        self._loop: ControlLoop | None = None
        self._overruns = 0
        self._previous: Cycle | None = None
        self._wait = 0.0
        self._wait_before_previous = 0.0
        self._collections = 0
        self._collections_before_previous = 0
        self._collections_at_previous = 0

    def _collected(self, phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            self._collections += 1

    def on_start(self, loop: ControlLoop) -> None:
        self._loop = loop
        self._overruns = loop.report.overruns
        self._previous = None
        self._wait = float(getattr(loop.backend, "sync_wait", 0.0))
        gc.callbacks.append(self._collected)

    def on_cycle(self, cycle: Cycle) -> str | None:
        assert self._loop is not None
        wait = float(getattr(self._loop.backend, "sync_wait", 0.0))
        self._after_previous(cycle.t)
        self._previous = cycle
        self._wait_before_previous, self._wait = wait - self._wait, wait
        self._collections_before_previous = self._collections_at_previous
        self._collections_at_previous = self._collections
        return None

    def _record(self, late: Cycle, next_start: float) -> LateCycle:
        output = late.output
        allocation = output.allocation
        contacts = output.contacts
        return LateCycle(
            t=late.t,
            period_s=late.context.dt,
            stage=late.stage,
            status=output.status,
            cycle_s=late.cycle_time,
            estimate_s=output.estimate_time,
            solve_s=0.0 if allocation is None else allocation.solve_time,
            solver_s=0.0 if allocation is None else allocation.solver_time,
            contacts=0 if contacts is None else len(contacts),
            joint_wait_s=self._wait_before_previous,
            to_next_s=next_start - late.t,
            collections=self._collections - self._collections_before_previous,
        )

    def _after_previous(self, t: float) -> None:
        """Keep the previous cycle if the loop counted an overrun after it; ``t`` [s] is when
        the next cycle started (or the run ended)."""
        assert self._loop is not None
        overruns = self._loop.report.overruns
        if overruns > self._overruns and self._previous is not None:
            self.count += 1
            if len(self.kept) < MOST_KEPT:
                self.kept.append(self._record(self._previous, t))
        self._overruns = overruns

    def on_end(self, loop: ControlLoop) -> None:
        self._after_previous(loop.backend.time)
        self._previous = None
        if self._collected in gc.callbacks:
            gc.callbacks.remove(self._collected)

    def as_list(self) -> list[dict[str, Any]]:
        """The kept records as JSON-ready dicts."""
        return [asdict(late) for late in self.kept]
