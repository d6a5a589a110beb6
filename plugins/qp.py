"""The paper's whole-hand force-allocation QP (Sec. III-C), with and without actuation consistency.

Per cycle: build the QP over every current contact, palm included
(:func:`wholehand.allocation.problem.build_allocation_qp`), solve it with the named solver
(:func:`wholehand.allocation.solve.solve_allocation`, warm-started from the previous cycle) and
command ``tau* = J_act^T f_act*``. A failed or infeasible solve never raises: it returns no
torque, with the status; the control loop keeps the last feasible torque.

Joints. By default all ``n_v`` columns of ``J_world`` are commanded joints. With
``actuated_dofs`` only those are: the torque limits and ``J_act`` (hence the consistency basis)
use their columns only, and every other joint gets ``tau = 0`` and no constraint. This fits joints
driven by something else (a floating base, an arm under position control): forces they would
have to resist are not this allocator's to command, and constraining ``J^T f`` to zero on them
would wrongly forbid the hand from pushing against the arm. A truly free passive joint would
need ``J^T f = 0`` on it, which the paper's model (all hand joints actuated) does not have.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import numpy.typing as npt

from wholehand import defaults
from wholehand.allocation.base import (
    Allocation,
    AllocationStatus,
    Allocator,
    checked_jacobians,
    is_balanced,
)
from wholehand.allocation.kernel_loading import load_kernels
from wholehand.allocation.kernels import finite_inputs
from wholehand.allocation.options import SolveOptions
from wholehand.allocation.problem import (
    N_EDGES,
    REG,
    AllocationParams,
    AllocationQP,
    build_allocation_qp,
)
from wholehand.allocation.solve import (
    AllocationSolution,
    binding_rows,
    solve_allocation,
)
from wholehand.allocation.solvers import make_solver
from wholehand.allocation.solvers.dual_active_set import (
    DUAL_ACTIVE_SET,
    FALLBACK_SOLVER,
    MAX_STEPS,
    solve_dual_active_set,
)
from wholehand.allocation.warm_start import (
    WarmStart,
    rows_of_joints,
    warm_edge_weights,
)
from wholehand.contacts.base import ContactSet

if TYPE_CHECKING:
    from wholehand.models.kinematics import HandKinematics

FloatArray = npt.NDArray[np.float64]


STEP_NS_START: float = 5000.0
"""The dual active-set solver's time per step [ns] assumed until it is measured."""
STEP_SAMPLE: int = 8
"""Solves of fewer steps do not update the measured time per step (fixed costs dominate)."""
STEP_GAIN: float = 0.2
"""Weight of each new measurement in the time per step's running average."""

SOLVE_SHARE: float = 0.75
"""Share of the deadline (:attr:`~wholehand.allocation.options.SolveOptions.deadline`) the
solving may use. The rest is for what follows the
solver's stop: up to 32 more DAQP iterations between its clock checks (about 200 us near a
loss on the development machine) and the allocator's finishing work (docs/results.md)."""


class QPAllocator(Allocator):
    """Whole-hand force-allocation QP with actuation consistency (paper Sec. III-C)."""

    consistency_default: ClassVar[bool] = True
    supports_external_wrench: ClassVar[bool] = True
    supports_tau_bias: ClassVar[bool] = True

    def __init__(
        self,
        *,
        mu: float = defaults.MU,
        f_n_min: float = defaults.F_N_MIN,
        tau_max: float | npt.ArrayLike = defaults.TAU_MAX,
        eps_margin: float = defaults.EPS_MARGIN,
        svd_tol: float = defaults.SVD_TOL,
        reg: float = REG,
        consistency: bool | None = None,
        actuated_dofs: npt.ArrayLike | None = None,
        options: SolveOptions | Mapping[str, Any] | None = None,
    ) -> None:
        """Args:
        mu: Friction coefficient of the 4-sided pyramid [-], >= 0.
        f_n_min: Lower bound on the sum of normal forces [N], >= 0.
        tau_max: Torque limit per joint [N*m], > 0: a scalar or an (n_v,) array (``inf``
            removes a joint's rows).
        eps_margin: Bound on each force component in the SVD basis of ``Null(J_act^T)`` [N].
        svd_tol: Absolute singular-value tolerance deciding ``rank(J_act)``.
        reg: Ridge weight of the tie-break on the pyramid-edge weights (see
            :mod:`wholehand.allocation.problem`), > 0.
        consistency: Impose the actuation-consistency rows; None: the class default.
        actuated_dofs: Commanded joints: an (n_v,) boolean mask or joint indices; None: all.
        options: How the QP is solved (:class:`~wholehand.allocation.options.SolveOptions`:
            the solver, warm start, screening, tolerances, deadline), or a mapping of its
            fields; None: the defaults.

        Raises:
            ConfigError: A value is out of range or the solver is not installed.
        """
        owner = type(self).__name__
        self.params = AllocationParams.checked(
            owner,
            mu=mu,
            f_n_min=f_n_min,
            tau_max=tau_max,
            eps_margin=eps_margin,
            svd_tol=svd_tol,
            reg=reg,
            consistency=self.consistency_default if consistency is None else consistency,
            actuated_dofs=actuated_dofs,
        )
        self.options = SolveOptions.of(options, owner)
        """The checked solve options (``deadline_after_miss`` resolved)."""
        self._missed = False  # the last allocation ran out of time
        self._dual_active_set = self.options.solver == DUAL_ACTIVE_SET
        self._step_ns = STEP_NS_START  # the dual active-set solver's measured time per step
        # The dual active-set method solves the structured problem itself; the dense solver
        # then serves where it fails (FALLBACK_SOLVER), with the user's settings.
        dense = FALLBACK_SOLVER if self._dual_active_set else self.options.solver
        self.qp_solver = make_solver(dense, self.options.solver_settings, owner)
        self._warm = WarmStart(match_radius=self.options.match_radius)
        self.counts: Counter[AllocationStatus] = Counter()
        """Allocations per status since construction (or :meth:`reset`)."""
        self.last_solution: AllocationSolution | None = None
        """Solver outcome of the last cycle that reached the solver, for debugging."""
        # Here, not in the first control cycle.
        load_kernels(self.params, self.qp_solver, self._dual_active_set)

    # --------------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the warm start and the counts."""
        self._warm.clear()
        self.qp_solver.reset()
        self.counts.clear()
        self.last_solution = None
        self._missed = False

    def _result(
        self,
        status: AllocationStatus,
        n: int,
        n_v: int,
        *,
        tau: FloatArray | None = None,
        f_local: FloatArray | None = None,
        f_world: FloatArray | None = None,
        wrench: FloatArray | None = None,
        solve_time: float = 0.0,
        solver_time: float = 0.0,
    ) -> Allocation:
        self.counts[status] += 1
        self._missed = status is AllocationStatus.DEADLINE
        return Allocation(
            f_local=np.zeros((n, 3)) if f_local is None else f_local,
            f_world=np.zeros((n, 3)) if f_world is None else f_world,
            tau=tau,
            residual_wrench=np.zeros(6) if wrench is None else wrench,
            status=status,
            solve_time=solve_time,
            solver_time=solver_time,
            solver=self.options.solver,
        )

    # --------------------------------------------------------------------------------------------
    def allocate(
        self,
        contacts: ContactSet,
        J_world: FloatArray,
        p_com_world: FloatArray,
        kinematics: HandKinematics | None = None,
        *,
        external_wrench: FloatArray | None = None,
        tau_bias: FloatArray | None = None,
    ) -> Allocation:
        """Contact forces and joint torques for the current contacts.

        Args:
            contacts: The N contacts of this cycle.
            J_world: (N, 3, n_v) point Jacobians at the contact points, world axes.
            p_com_world: (3,) object centre of mass, world frame [m].
            kinematics: unused (the QP needs only the Jacobians).
            external_wrench: (6,) known wrench on the object about its COM, world axes
                [N, N*m] (its weight, say): the QP balances ``G f + w``; None: zero (paper).
            tau_bias: (n_v,) torque the joints command besides the contact forces [N*m] (the
                hand links' weight, :class:`~wholehand.models.gravity.GravityCompensation`):
                the torque rows limit ``tau_bias + J_act^T f``; the returned ``tau`` is the
                contact part ``J_act^T f`` alone. None: zero (paper).

        Returns:
            The allocation. ``EMPTY`` / ``NO_ACTUATED_CONTACT``: zero forces and torque (zero
            is a feasible command); ``INFEASIBLE`` / ``SOLVER_FAILED`` (also for NaN/inf inputs
            and a non-finite solution) / ``INACCURATE`` (a solution violating a constraint by
            more than ``feas_tol``, relative) / ``DEADLINE``: zero forces and no torque
            (``tau=None``: keep the last feasible one); ``OK`` (the forces balance the object)
            / ``UNBALANCED`` (they do not): the new forces and torque. ``solve_time`` is the
            wall time of building and solving the QP (all screening rounds) [s].

        Raises:
            ConfigError: Shapes of ``J_world`` / ``p_com_world`` do not match the contacts, or
                ``tau_max`` / ``actuated_dofs`` do not match ``n_v``.
        """
        owner = type(self).__name__
        n = len(contacts)
        J_world = checked_jacobians(J_world, n, owner)
        n_v = J_world.shape[2]
        self.params.dofs_and_limits(n_v, owner)  # shape errors raise even without contacts
        if n == 0:
            self._warm.clear()
            return self._result(AllocationStatus.EMPTY, 0, n_v, tau=np.zeros(n_v))
        if not contacts.actuated.any():
            self._warm.clear()
            return self._result(AllocationStatus.NO_ACTUATED_CONTACT, n, n_v, tau=np.zeros(n_v))

        t0 = time.perf_counter_ns()
        p_com = np.asarray(p_com_world, dtype=np.float64)
        if not (
            finite_inputs(contacts.p_world, contacts.n_world, J_world, p_com)
            and (tau_bias is None or np.isfinite(tau_bias).all())
        ):
            self._warm.clear()
            return self._result(AllocationStatus.SOLVER_FAILED, n, n_v, solve_time=_since(t0))
        qp = build_allocation_qp(
            contacts, J_world, p_com, self.params, owner, external_wrench, tau_bias
        )
        sol = self._solve(qp, contacts, t0)
        self.last_solution = sol
        dt = _since(t0)
        if sol.status == "deadline":
            # The problem is fine, only slow: the next cycle starts from the progress made.
            self._remember_progress(qp, contacts, sol)
            return self._result(
                AllocationStatus.DEADLINE, n, n_v, solve_time=dt, solver_time=sol.solver_time
            )
        if sol.x is None or sol.relative_violation > self.options.feas_tol:
            self._warm.clear()
            status = AllocationStatus.SOLVER_FAILED
            if sol.x is not None:
                status = AllocationStatus.INACCURATE
            elif sol.status == "infeasible":
                status = AllocationStatus.INFEASIBLE
            return self._result(status, n, n_v, solve_time=dt, solver_time=sol.solver_time)
        lam = sol.x[: qp.n_lambda]
        tau = qp.tau(lam)
        self._remember(qp, contacts, sol, sol.x)
        f_world = qp.f_world(lam)
        wrench = qp.G_lam @ lam + qp.w_ext
        return self._result(
            AllocationStatus.OK if is_balanced(wrench, f_world) else AllocationStatus.UNBALANCED,
            n,
            n_v,
            tau=tau,
            f_local=qp.f_local(lam),
            f_world=f_world,
            wrench=wrench,
            solve_time=dt,
            solver_time=sol.solver_time,
        )

    def _solve(self, qp: AllocationQP, contacts: ContactSet, t0: int) -> AllocationSolution:
        """The cycle's solution: by the dual active-set method where it is chosen (the dense
        fallback solver where it fails), else by screening with the dense solver."""
        budget = self.options.deadline_after_miss if self._missed else self.options.deadline
        deadline_ns = None if budget is None else t0 + int(budget * SOLVE_SHARE * 1e9)
        if self._dual_active_set:
            sol = self._solve_dual(qp, contacts, deadline_ns)
            if sol is not None:
                return sol
        kwargs = self._warm_kwargs(qp, contacts) if self.options.warm_start else {}
        return solve_allocation(
            qp,
            self.qp_solver,
            screening=self.options.screening,
            screen_tol=self.options.screen_tol,
            deadline_ns=deadline_ns,
            **kwargs,
        )

    def _solve_dual(
        self, qp: AllocationQP, contacts: ContactSet, deadline_ns: int | None
    ) -> AllocationSolution | None:
        """The dual active-set solution, or None where the fallback solver must answer. Under
        a deadline the solve gets the steps that fit in the time left at its measured time per
        step; one stopped by them is a ``"deadline"`` solution."""
        start = self._warm.dual_start(qp, contacts) if self.options.warm_start else (None,) * 3
        max_steps = MAX_STEPS
        if deadline_ns is not None:
            left = deadline_ns - time.perf_counter_ns()
            max_steps = min(MAX_STEPS, int(max(left, 0) / self._step_ns))
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
            self._step_ns += STEP_GAIN * (per_step - self._step_ns)
        if sol.x is not None:
            self._warm.keep_sides(qp, dual.y, dual.null_scale)
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

    # --------------------------------------------------------------------------------------------
    def _warm_kwargs(self, qp: AllocationQP, contacts: ContactSet) -> dict[str, Any]:
        warm = self._warm
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
            lam = np.where(np.isinf(lam0), self.params.f_n_min / qp.n_lambda, lam0).ravel()
            out["x0"] = np.concatenate((lam, qp.G_lam @ lam + qp.w_ext))
        return out

    def _remember(
        self, qp: AllocationQP, contacts: ContactSet, sol: AllocationSolution, x: FloatArray
    ) -> None:
        """The next cycle starts from ``x`` (the solution, or the last finished round's after a
        deadline) and the rows at or past their bounds there (``sol``'s row values are at
        ``x``): the binding ones, and after a deadline also those still to add."""
        warm = self._warm
        t, z = binding_rows(qp, sol)
        warm.p_world = contacts.p_world.copy()
        warm.link = contacts.link.copy()
        warm.lam = x[: qp.n_lambda].reshape(-1, N_EDGES).copy()
        warm.torque_dofs = qp.dofs[qp.torque_rows[t]]
        warm.null_rows = z

    def _remember_progress(
        self, qp: AllocationQP, contacts: ContactSet, sol: AllocationSolution
    ) -> None:
        """After a deadline: the next cycle starts with every row this one had to add, and
        from the last finished round's edge weights when there is one."""
        if sol.x_relaxed is not None:
            self._remember(qp, contacts, sol, sol.x_relaxed)
        else:
            same = self._warm.same_links(contacts.link)
            self._warm.add_rows(
                qp.dofs[qp.torque_rows[sol.torque_sel]], sol.null_sel if same else sol.null_sel[:0]
            )


class QPNoConsistencyAllocator(QPAllocator):
    """Whole-hand force-allocation QP without the actuation-consistency rows (paper ablation)."""

    consistency_default: ClassVar[bool] = False


def _since(t0: int) -> float:
    return (time.perf_counter_ns() - t0) * 1e-9


__all__ = ["QPAllocator", "QPNoConsistencyAllocator"]
