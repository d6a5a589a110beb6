"""How the allocation QP is solved: the solver and the speed machinery around it.

None of these options changes the problem or its optimum (:mod:`wholehand.allocation.problem`);
they decide how fast, with what worst case and how exactly the optimum is found
(docs/performance.md). :class:`~wholehand_plugins.qp.QPAllocator` takes the paper's parameters
and one :class:`SolveOptions`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from wholehand.allocation.solve import FEAS_TOL, SCREEN_TOL
from wholehand.allocation.solvers import DEFAULT_SOLVER
from wholehand.allocation.warm_start import MATCH_RADIUS
from wholehand.errors import ConfigError


@dataclass(frozen=True)
class SolveOptions:
    """How an allocator solves its QP (module docstring)."""

    solver: str = DEFAULT_SOLVER
    """QP solver name, see :func:`wholehand.allocation.solvers.available_solvers`.
    ``"dual_active_set"``: the solver built for this QP
    (:mod:`~wholehand.allocation.solvers.dual_active_set`; warm-started from the last cycle's
    support and active rows, DAQP where it fails), which needs no screening: ``screening``,
    ``screen_edges``, ``screen_tol`` and ``deadline`` apply to the DAQP fallback alone."""
    solver_settings: Mapping[str, Any] | None = None
    """Solver settings on top of the adapter's tight defaults."""
    warm_start: bool = True
    """Start each solve from the previous cycle's matched solution."""
    screening: bool = True
    """Solve with a working subset of torque/consistency rows (exact)."""
    screen_edges: bool = False
    """Screen the pyramid-edge weights too, as the rows are (exact; with solvers that report
    multipliers, DAQP): each cycle starts with the edges that carried force last cycle plus
    every edge of a new contact, adds any left-out edge whose multiplier shows it would lower
    the objective, and starts each screening round from the last round's active set. Near a
    loss most edge weights are zero, so the problems stay small: a bounded worst case. Off by
    default: the solver then takes another path to the same optimum, which moves the torques by
    up to about 1e-4 N*m (the 1e-6 ridge that fixes the optimum magnifies the solver's
    tolerances), enough to change simulated trajectories near a loss, and the committed study
    rows were made without it. The hardware controller turns it on."""
    feas_tol: float = FEAS_TOL
    """Largest relative constraint violation of an accepted solution [-]: a torque's excess
    over its joint's limit as a fraction of the limit, a force constraint's as a fraction of the
    allocation's force scale (see
    :attr:`~wholehand.allocation.solution.AllocationSolution.relative_violation`); beyond it the
    allocation is ``INACCURATE``."""
    screen_tol: float = SCREEN_TOL
    """Violation above which a left-out row joins the working set."""
    match_radius: float = MATCH_RADIUS
    """Contacts on one link closer than this across cycles are the same [m]."""
    deadline: float | None = None
    """Time budget of one allocation, from its start [s]. The solving stops at
    :data:`~wholehand_plugins.qp.SOLVE_SHARE` of it: DAQP and OSQP stop themselves there (they
    check the clock every few dozen iterations), other solvers finish the solve under way, and
    no screening round starts past it; the rest of the budget covers the solver's last
    iterations and the allocator's own finishing work. An allocation not exact by then ends as
    ``DEADLINE`` (no torque: the loop keeps the last feasible one). None: no deadline, so
    simulation results do not depend on the machine's speed."""
    deadline_after_miss: float | None = None
    """Time budget of an allocation that follows a ``DEADLINE`` one [s], at least ``deadline``
    (None: ``deadline``). The missed allocation hands its progress to the next, which with a
    little more time usually finishes: near a loss the misses then come singly instead of in
    runs of tens of cycles."""

    @classmethod
    def of(cls, value: SolveOptions | Mapping[str, Any] | None, owner: str) -> SolveOptions:
        """``value`` as checked options: options, a mapping of their fields (a config file's
        or a study's ``allocator_params``) or None (the defaults); ``deadline_after_miss``
        resolved to the budget it means.

        Raises:
            ConfigError: an unknown key or a value out of range, named with ``owner``.
        """
        if value is None:
            value = cls()
        elif isinstance(value, Mapping):
            fields = [f.name for f in dataclasses.fields(cls)]
            unknown = sorted(set(value) - set(fields))
            if unknown:
                raise ConfigError(
                    f"{owner}: unknown solve options {unknown}; the options are {fields}"
                )
            value = cls(**value)
        elif not isinstance(value, cls):
            raise ConfigError(
                f"{owner}: options={value!r} is invalid; pass SolveOptions(...), a mapping of "
                "its fields, or None"
            )
        return value._checked(owner)

    def _checked(self, owner: str) -> SolveOptions:
        deadline, after_miss = self.deadline, self.deadline_after_miss
        if deadline is not None and not (isinstance(deadline, int | float) and deadline > 0):
            raise ConfigError(
                f"{owner}: option deadline={deadline!r} is invalid; it must be a time > 0 [s] "
                "or None"
            )
        if after_miss is not None and not (
            isinstance(after_miss, int | float)
            and deadline is not None
            and deadline <= after_miss < np.inf
        ):
            raise ConfigError(
                f"{owner}: option deadline_after_miss={after_miss!r} is invalid; it must be a "
                f"time [s] at least deadline={deadline!r}, which must be set, or None"
            )
        for name in ("feas_tol", "screen_tol", "match_radius"):
            number = getattr(self, name)
            if not (isinstance(number, int | float) and 0.0 <= number < np.inf):
                raise ConfigError(
                    f"{owner}: option {name}={number!r} is invalid; it must be a finite number >= 0"
                )
        if self.solver_settings is not None and not isinstance(self.solver_settings, Mapping):
            raise ConfigError(
                f"{owner}: option solver_settings={self.solver_settings!r} is invalid; it must "
                "be a mapping of setting names to values"
            )
        return dataclasses.replace(
            self,
            warm_start=bool(self.warm_start),
            screening=bool(self.screening),
            screen_edges=bool(self.screen_edges),
            feas_tol=float(self.feas_tol),
            screen_tol=float(self.screen_tol),
            match_radius=float(self.match_radius),
            deadline=None if deadline is None else float(deadline),
            deadline_after_miss=(
                None if deadline is None else float(deadline if after_miss is None else after_miss)
            ),
        )


__all__ = ["SolveOptions"]
