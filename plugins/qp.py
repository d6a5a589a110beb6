"""The paper's whole-hand force-allocation QP (Sec. III-C), with and without actuation consistency.

Per cycle (:meth:`QPAllocator.allocate`): check the inputs, build the QP over every current
contact, palm included (:func:`wholehand.allocation.problem.build_allocation_qp`), solve it
(:class:`wholehand.allocation.cycle_solver.CycleSolver`: the named solver, warm-started from the
previous cycle, within the deadline) and command ``tau* = J_act^T f_act*``. A failed or
infeasible solve never raises: it returns no torque, with the status; the control loop keeps the
last feasible torque.

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
from wholehand.allocation.cycle_solver import CycleSolver
from wholehand.allocation.kernels import finite_inputs
from wholehand.allocation.options import SolveOptions
from wholehand.allocation.problem import REG, AllocationParams, build_allocation_qp
from wholehand.allocation.solve import AllocationSolution
from wholehand.contacts.base import ContactSet

if TYPE_CHECKING:
    from wholehand.models.kinematics import HandKinematics

FloatArray = npt.NDArray[np.float64]


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
        self.cycle_solver = CycleSolver(self.params, self.options, owner)
        """The solving carried from cycle to cycle: warm start, deadline, solver."""
        self.counts: Counter[AllocationStatus] = Counter()
        """Allocations per status since construction (or :meth:`reset`)."""
        self.last_solution: AllocationSolution | None = None
        """Solver outcome of the last cycle that reached the solver, for debugging."""

    # --------------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the warm start and the counts."""
        self.cycle_solver.reset()
        self.counts.clear()
        self.last_solution = None

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
            self.cycle_solver.forget()
            return self._result(AllocationStatus.EMPTY, 0, n_v, tau=np.zeros(n_v))
        if not contacts.actuated.any():
            self.cycle_solver.forget()
            return self._result(AllocationStatus.NO_ACTUATED_CONTACT, n, n_v, tau=np.zeros(n_v))

        t0 = time.perf_counter_ns()
        p_com = np.asarray(p_com_world, dtype=np.float64)
        if not (
            finite_inputs(contacts.p_world, contacts.n_world, J_world, p_com)
            and (tau_bias is None or np.isfinite(tau_bias).all())
        ):
            self.cycle_solver.forget()
            return self._result(AllocationStatus.SOLVER_FAILED, n, n_v, solve_time=_since(t0))
        qp = build_allocation_qp(
            contacts, J_world, p_com, self.params, owner, external_wrench, tau_bias
        )
        sol = self.cycle_solver.solve(qp, contacts, t0)
        self.last_solution = sol
        dt = _since(t0)
        if not self.cycle_solver.keep(qp, contacts, sol):
            status = AllocationStatus.SOLVER_FAILED
            if sol.status == "deadline":  # only slow: the next cycle goes on from here
                status = AllocationStatus.DEADLINE
            elif sol.x is not None:
                status = AllocationStatus.INACCURATE
            elif sol.status == "infeasible":
                status = AllocationStatus.INFEASIBLE
            return self._result(status, n, n_v, solve_time=dt, solver_time=sol.solver_time)
        assert sol.x is not None
        lam = sol.x[: qp.n_lambda]
        f_world = qp.f_world(lam)
        wrench = qp.G_lam @ lam + qp.w_ext
        return self._result(
            AllocationStatus.OK if is_balanced(wrench, f_world) else AllocationStatus.UNBALANCED,
            n,
            n_v,
            tau=qp.tau(lam),
            f_local=qp.f_local(lam),
            f_world=f_world,
            wrench=wrench,
            solve_time=dt,
            solver_time=sol.solver_time,
        )


class QPNoConsistencyAllocator(QPAllocator):
    """Whole-hand force-allocation QP without the actuation-consistency rows (paper ablation)."""

    consistency_default: ClassVar[bool] = False


def _since(t0: int) -> float:
    return (time.perf_counter_ns() - t0) * 1e-9


__all__ = ["QPAllocator", "QPNoConsistencyAllocator"]
