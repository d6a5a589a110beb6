"""How the allocation QP is solved from one control cycle to the next.

:class:`CycleSolver` holds what one cycle's solve leaves to the next: the solver chosen (the dual
active-set method with a dense fallback, or a dense solver with screening), the warm start (the
last solution's edge weights and binding rows, :mod:`wholehand.allocation.warm_start`), the
deadline's budget (longer right after a missed one), and the dual active-set solver's measured
time per step, which turns the budget into a number of steps. The allocator builds the paper's
QP (:mod:`wholehand.allocation.problem`) and hands it here; the maths of the problem does not
depend on any of this.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from wholehand.allocation.kernel_loading import load_kernels
from wholehand.allocation.options import SolveOptions
from wholehand.allocation.problem import N_EDGES, AllocationParams, AllocationQP
from wholehand.allocation.solve import AllocationSolution, binding_rows, solve_allocation
from wholehand.allocation.solvers import make_solver
from wholehand.allocation.solvers.dual_active_set import (
    DUAL_ACTIVE_SET,
    FALLBACK_SOLVER,
    MAX_STEPS,
    solve_dual_active_set,
)
from wholehand.allocation.warm_start import WarmStart, rows_of_joints, warm_edge_weights
from wholehand.contacts.base import ContactSet

STEP_NS_START: float = 5000.0
"""The dual active-set solver's time per step [ns] assumed until it is measured."""
STEP_SAMPLE: int = 8
"""Solves of fewer steps do not update the measured time per step (fixed costs dominate)."""
STEP_GAIN: float = 0.2
"""Weight of each new measurement in the time per step's running average."""

SOLVE_SHARE: float = 0.75
"""Share of the deadline (:attr:`~wholehand.allocation.options.SolveOptions.deadline`) the
solving may use. The rest is for what follows the solver's stop: up to 32 more DAQP iterations
between its clock checks (about 200 us near a loss on the development machine) and the
allocator's finishing work (docs/performance.md)."""


class CycleSolver:
    """Solves each cycle's allocation QP, warm-started from the last cycle, within the deadline.

    Args:
        params: the allocator's checked parameters (the kernels are compiled for them here, not
            in the first control cycle).
        options: how to solve (:class:`~wholehand.allocation.options.SolveOptions`).
        owner: the allocator's name, for error messages.

    Raises:
        ConfigError: the solver is not installed.
    """

    def __init__(self, params: AllocationParams, options: SolveOptions, owner: str) -> None:
        self.options = options
        self.f_n_min = params.f_n_min
        self.dual_active_set = options.solver == DUAL_ACTIVE_SET
        # The dual active-set method solves the structured problem itself; the dense solver
        # then serves where it fails (FALLBACK_SOLVER), with the user's settings.
        dense = FALLBACK_SOLVER if self.dual_active_set else options.solver
        self.qp_solver = make_solver(dense, options.solver_settings, owner)
        self.warm = WarmStart(match_radius=options.match_radius)
        self.missed = False
        """The last allocation ran out of time: this one gets ``deadline_after_miss``."""
        self.step_ns = STEP_NS_START
        """The dual active-set solver's measured time per step [ns]."""
        load_kernels(params, self.qp_solver, self.dual_active_set)

    def reset(self) -> None:
        """Forget the warm start, the missed deadline and the dense solver's state."""
        self.warm.clear()
        self.qp_solver.reset()
        self.missed = False

    def forget(self) -> None:
        """A cycle without a QP to solve (no contact, bad inputs): the next starts cold."""
        self.warm.clear()
        self.missed = False

    # --------------------------------------------------------------------------------------------
    def solve(self, qp: AllocationQP, contacts: ContactSet, t0: int) -> AllocationSolution:
        """The cycle's solution of ``qp`` over ``contacts``, the cycle having started at ``t0``
        [ns, ``time.perf_counter_ns``]: by the dual active-set method where it is chosen (the
        dense fallback solver where it fails), else by screening with the dense solver. A
        solve stopped by the deadline is a ``"deadline"`` solution. Call :meth:`keep` with it."""
        options = self.options
        budget = options.deadline_after_miss if self.missed else options.deadline
        deadline_ns = None if budget is None else t0 + int(budget * SOLVE_SHARE * 1e9)
        if self.dual_active_set:
            sol = self._solve_dual(qp, contacts, deadline_ns)
            if sol is not None:
                return sol
        kwargs = self._warm_kwargs(qp, contacts) if options.warm_start else {}
        return solve_allocation(
            qp,
            self.qp_solver,
            screening=options.screening,
            screen_tol=options.screen_tol,
            deadline_ns=deadline_ns,
            **kwargs,
        )

    def keep(self, qp: AllocationQP, contacts: ContactSet, sol: AllocationSolution) -> bool:
        """Carry ``sol`` to the next cycle; whether it is usable (a solution within
        ``feas_tol``). A deadline keeps the progress made (the next cycle starts from it, with
        the longer budget); a failure starts the next cycle cold."""
        self.missed = sol.status == "deadline"
        if self.missed:
            self._keep_progress(qp, contacts, sol)
            return False
        if sol.x is None or sol.relative_violation > self.options.feas_tol:
            self.warm.clear()
            return False
        self._remember(qp, contacts, sol, sol.x)
        return True

    # --------------------------------------------------------------------------------------------
    def _solve_dual(
        self, qp: AllocationQP, contacts: ContactSet, deadline_ns: int | None
    ) -> AllocationSolution | None:
        """The dual active-set solution, or None where the fallback solver must answer. Under
        a deadline the solve gets the steps that fit in the time left at its measured time per
        step."""
        start = self.warm.dual_start(qp, contacts) if self.options.warm_start else (None,) * 3
        max_steps = MAX_STEPS
        if deadline_ns is not None:
            left = deadline_ns - time.perf_counter_ns()
            max_steps = min(MAX_STEPS, int(max(left, 0) / self.step_ns))
        limited = max_steps < MAX_STEPS  # by the deadline
        try:
            dual = solve_dual_active_set(qp, *start, max_steps=max_steps)
            if dual.solution.status == "failed" and start[0] is not None:
                # A warm start that rounding led astray: a cold solve, with the steps left.
                max_steps -= dual.solution.iterations
                if max_steps > 0:
                    dual = solve_dual_active_set(qp, max_steps=max_steps)
        except Exception:  # the loop must not raise: the fallback solver answers
            return None
        sol = dual.solution
        if sol.iterations >= STEP_SAMPLE:
            per_step = sol.solver_time * 1e9 / sol.iterations
            self.step_ns += STEP_GAIN * (per_step - self.step_ns)
        if sol.x is not None:
            self.warm.keep_sides(qp, dual.y, dual.null_scale)
        if sol.status in ("optimal", "infeasible"):
            return sol
        if limited and sol.iterations >= max_steps:
            return AllocationSolution(
                None,
                "deadline",
                1,
                sol.n_rows,
                sol.iterations,
                np.inf,
                detail="deadline passed before the solution was exact",
                solver_time=sol.solver_time,
            )
        return None

    def _warm_kwargs(self, qp: AllocationQP, contacts: ContactSet) -> dict[str, Any]:
        """The dense solve's warm start: the rows binding last cycle, the edges that carried
        force, and the last weights as a primal start where the solver takes one."""
        warm = self.warm
        if warm.lam is None:
            return {}
        torque_sel = rows_of_joints(warm.torque_dofs, qp.n_v, qp.dofs, qp.torque_rows)
        null_sel = warm.null_rows if warm.same_links(contacts.link) else None
        out: dict[str, Any] = {"warm": True, "torque_sel": torque_sel, "null_sel": null_sel}
        use_edges = self.options.screen_edges and self.qp_solver.reports_duals
        if not (self.qp_solver.primal_warm_start or use_edges):
            return out
        # Each contact's edge weights last cycle (inf for a new contact: every edge), and the
        # edges that carried force then, with every edge of a new contact.
        lam0, carried = warm_edge_weights(warm.match(contacts.p_world, contacts.link), warm.lam)
        if use_edges:
            out["edge_sel"] = carried
        if self.qp_solver.primal_warm_start:
            lam = np.where(np.isinf(lam0), self.f_n_min / qp.n_lambda, lam0).ravel()
            out["x0"] = np.concatenate((lam, qp.G_lam @ lam + qp.w_ext))
        return out

    def _remember(
        self,
        qp: AllocationQP,
        contacts: ContactSet,
        sol: AllocationSolution,
        x: np.ndarray[Any, np.dtype[np.float64]],
    ) -> None:
        """The next cycle starts from ``x`` (the solution, or the last finished round's after a
        deadline) and the rows at or past their bounds there (``sol``'s row values are at
        ``x``): the binding ones, and after a deadline also those still to add."""
        warm = self.warm
        t, z = binding_rows(qp, sol)
        warm.p_world = contacts.p_world.copy()
        warm.link = contacts.link.copy()
        warm.lam = x[: qp.n_lambda].reshape(-1, N_EDGES).copy()
        warm.torque_dofs = qp.dofs[qp.torque_rows[t]]
        warm.null_rows = z

    def _keep_progress(
        self, qp: AllocationQP, contacts: ContactSet, sol: AllocationSolution
    ) -> None:
        """After a deadline: the next cycle starts with every row this one had to add, and
        from the last finished round's edge weights when there is one."""
        if sol.x_relaxed is not None:
            self._remember(qp, contacts, sol, sol.x_relaxed)
        else:
            same = self.warm.same_links(contacts.link)
            self.warm.add_rows(
                qp.dofs[qp.torque_rows[sol.torque_sel]], sol.null_sel if same else sol.null_sel[:0]
            )
