"""``solver="dual_active_set"``: a solver built for the allocation QP.

The general solvers take the solved form as a dense QP (``[lambda; w]`` with the wrench
equality) and pay near a loss for its size: ~200 edge weights, most of them zero at the optimum,
and up to ~125 consistency rows, few of them binding. This one solves the problem in the edge
weights alone (:mod:`~wholehand.allocation.solvers.dual_active_set_kernel`): Goldfarb and
Idnani's dual active-set method over the weights that carry force, the objective's rank-6
structure used through a Cholesky factor of size 6 plus the active rows, and a warm start from
the weights and rows that were active last cycle (matched by contact). It starts from zero
force, so it needs no feasible point, and it reports the multipliers of every constraint.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from wholehand.allocation.problem import AllocationQP
from wholehand.allocation.solution import AllocationSolution
from wholehand.allocation.solve import violations
from wholehand.allocation.solvers.dual_active_set_kernel import (
    INFEASIBLE,
    ITERATION_LIMIT,
    NUMERICAL,
    OPTIMAL,
    dual_active_set,
)

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

DUAL_ACTIVE_SET = "dual_active_set"
"""The solver's name in :class:`~wholehand.allocation.options.SolveOptions`."""
FALLBACK_SOLVER = "daqp"
"""The dense solver that solves a cycle where the dual active-set method fails (an iteration
limit, or a factor that rounding made indefinite)."""
TOL: float = 1e-9
"""Violation of a constraint (per unit norm of its row) [N or N*m] accepted at the end."""
MAX_STEPS: int = 2000
"""Steps before the solve gives up (cold solves near a loss take a few hundred)."""

_STATUS = {OPTIMAL: "optimal", INFEASIBLE: "infeasible", NUMERICAL: "failed"}

CERTIFICATE_TOL: float = 1e-6
"""Tolerance of :func:`infeasibility_certificate` (as OSQP's test of primal infeasibility):
``|A^T y + z|`` at most this much of the multipliers' size, and the bounds' gap ``b`` at
least this much of it [N or N*m per unit multiplier]."""


VERIFY_TOL: float = 1e-6
"""Largest relative violation (:attr:`AllocationSolution.relative_violation`) of a solution the
method calls optimal that is passed on; past it the solve counts as failed (rounding on a
nearly infeasible problem), and the allocator asks its fallback solver."""

_NO_QR = (np.zeros((0, 0)), np.zeros(0))


def allocation_rows(
    qp: AllocationQP,
) -> tuple[FloatArray, tuple[FloatArray, FloatArray], FloatArray, FloatArray]:
    """The QP's rows on the edge weights, ``lo <= rows lambda <= hi``: the minimum squeeze,
    the torque rows (in ``qp.torque_rows`` order), then the consistency rows.

    Returns ``(A, (qr, tau), lo, hi)``: the dense rows ``A``, and the Householder QR whose
    ``Q`` holds the consistency basis (:meth:`ActuationNullSpace.householder`), the
    consistency rows then left implicit; where the basis is held otherwise they are rows of
    ``A`` and ``qr`` is empty."""
    n = qp.n_lambda
    t_lo, t_hi = qp.torque_bounds()
    eps = qp.params.eps_margin
    dense = [np.ones((1, n)), qp.T_lam]
    qr = None if qp.null is None else qp.null.householder()
    if qr is None:
        dense.append(qp.null_rows(np.arange(qp.n_null, dtype=np.intp)))
    A = np.ascontiguousarray(np.concatenate(dense))
    lo = np.concatenate(([qp.params.f_n_min], t_lo, np.full(qp.n_null, -eps)))
    hi = np.concatenate(([np.inf], t_hi, np.full(qp.n_null, eps)))
    # C order, as the empty stand-in: one compiled kernel for both paths.
    house = _NO_QR if qr is None else (np.ascontiguousarray(qr[0]), qr[1])
    return A, house, lo, hi


class DualSolution(NamedTuple):
    """What :func:`solve_dual_active_set` returns."""

    solution: AllocationSolution
    """The solution (``x = [lambda; w]``, ``w`` the net wrench ``G_lam lambda + w_ext``; every
    torque and consistency row's value; ``iterations``: the steps)."""
    y: FloatArray
    """(m,) the multipliers of :func:`allocation_rows`' rows (> 0 at a lower bound, < 0 at an
    upper one, 0 inactive)."""
    null_scale: FloatArray
    """(n_null,) the consistency rows' norms as far as the solve formed them (the others:
    their common average), for the next cycle's choices."""


def _row_scales(
    qp: AllocationQP, A: FloatArray, m: int, null_scale: FloatArray | None
) -> FloatArray:
    """(m,) the rows' 2-norms: ``A``'s, and the consistency rows' as learnt (``null_scale``)
    or, unknown, their average: a row ``u^T W_act`` of a unit ``u`` has the squared norm
    ``2 mu^2 + (4 - 2 mu^2) sum_a (n_a . u_a)^2``, whose sum averages 1/3 (one of three
    coordinates per contact)."""
    out = np.empty(m)
    md = A.shape[0]
    out[:md] = np.sqrt(np.einsum("ij,ij->i", A, A))
    if null_scale is not None and null_scale.size == m - md:
        out[md:] = null_scale
    else:
        mu2 = qp.params.mu**2
        out[md:] = np.sqrt(2.0 * mu2 + (4.0 - 2.0 * mu2) / 3.0)
    return out


def infeasibility_certificate(
    qp: AllocationQP,
    A: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    y: FloatArray,
    z: FloatArray,
    tol: float = CERTIFICATE_TOL,
) -> bool:
    """True when the multipliers ``y`` (m,) of :func:`allocation_rows`' rows (> 0 at a lower
    bound, < 0 at an upper one) and ``z`` (n,) >= 0 of the bounds ``lambda >= 0`` prove that no
    edge weights meet the rows (Farkas): with every row scaled to unit norm, ``A^T y + z = 0``
    and ``b = lo . y+ + hi . y- > 0``, each within ``tol`` of the largest multiplier. For any
    ``lambda >= 0`` meeting the rows, ``y . A lambda >= b > 0`` while ``y . A lambda = -z .
    lambda <= 0``. Where the problem is infeasible but rounding hides it, the dual active-set
    method's multipliers diverge along such a ray."""
    md = A.shape[0]
    used = np.concatenate((np.arange(md), md + np.flatnonzero(y[md:])))  # dense + nonzero
    rows = np.vstack((A, qp.null_rows(used[md:] - md))) if used.size > md else A
    y_used = y[used]
    bound = np.where(y_used > 0.0, lo[used], np.where(y_used < 0.0, hi[used], 0.0))
    norms = np.sqrt(np.einsum("ij,ij->i", rows, rows))
    size = max(float(np.abs(y_used * norms).max(initial=0.0)), float(z.max(initial=0.0)))
    if not (size > 0.0 and np.isfinite(size)):
        return False
    at_bound = y_used != 0.0  # an infinite bound never carries a multiplier
    gap = float(bound[at_bound] @ y_used[at_bound])
    residual = float(np.abs(rows.T @ y_used + z).max(initial=0.0))
    return residual <= tol * size and gap >= tol * size


def solve_dual_active_set(
    qp: AllocationQP,
    free: BoolArray | None = None,
    rows: npt.NDArray[np.int8] | None = None,
    null_scale: FloatArray | None = None,
    tol: float = TOL,
    max_steps: int = MAX_STEPS,
) -> DualSolution:
    """Solve the allocation QP with the dual active-set method.

    Args:
        qp: The cycle's problem.
        free: (4N,) edge weights to start free (last cycle's support); None: all at zero.
        rows: (m,) rows of :func:`allocation_rows` to start at a bound (last cycle's binding
            rows): +1 the lower one, -1 the upper one, 0 none; None: none.
        null_scale: (n_null,) the consistency rows' norms a solve of the same rows learnt
            (:attr:`DualSolution.null_scale`); None: their average.
        tol: Violation accepted at the end (:data:`TOL`).
        max_steps: Steps before giving up (status ``"failed"``).

    Returns:
        The solution, the rows' multipliers and the consistency rows' norms
        (:class:`DualSolution`).
    """
    t0 = time.perf_counter_ns()
    n = qp.n_lambda
    A, (qr, tau), lo, hi = allocation_rows(qp)
    start = np.zeros(n, dtype=np.bool_) if free is None else np.ascontiguousarray(free, np.bool_)
    m = lo.size
    active = np.zeros(m, np.int8) if rows is None else np.ascontiguousarray(rows, np.int8)
    scale = _row_scales(qp, A, m, null_scale)
    lam, y, z, code, steps, values = dual_active_set(
        np.ascontiguousarray(qp.G_lam),
        qp.w_ext,
        qp.params.reg,
        A,
        qr,
        tau,
        qp.W,
        qp.act_idx,
        lo,
        hi,
        scale,
        start,
        active,
        tol,
        max_steps,
    )
    solver_time = (time.perf_counter_ns() - t0) * 1e-9
    n_t = qp.torque_rows.size
    torque_values, null_values = values[1 : 1 + n_t], values[1 + n_t :]
    status = _STATUS.get(code, "failed")
    detail = "iteration limit" if code not in _STATUS else f"dual active set: {status}"
    worst = relative = np.inf
    if code == OPTIMAL:
        null_worst = float(np.abs(null_values).max(initial=0.0)) - qp.params.eps_margin
        worst, relative = violations(qp, lam, torque_values, null_worst)
        if not relative <= VERIFY_TOL:
            status = "failed"
            detail = f"dual active set: inaccurate (relative violation {relative:.2g})"
    if status == "failed" and code != ITERATION_LIMIT:
        # Rounding hid an infeasible problem where the multipliers diverged along a ray that
        # proves it.
        if infeasibility_certificate(qp, A, lo, hi, y, z):
            status, detail = "infeasible", "dual active set: infeasible (certified by the ray)"
    if status != "optimal":
        failed = AllocationSolution(
            None, status, 1, m - 1, steps, worst, relative, detail, solver_time=solver_time
        )
        return DualSolution(failed, y, scale[A.shape[0] :])
    x = np.concatenate((lam, qp.G_lam @ lam + qp.w_ext))
    solution = AllocationSolution(
        x=x,
        status="optimal",
        rounds=1,
        n_rows=m - 1,
        iterations=steps,
        violation=worst,
        relative_violation=relative,
        detail="dual active set: optimal",
        solver_time=solver_time,
        torque_sel=np.arange(n_t, dtype=np.intp),
        null_sel=np.arange(qp.n_null, dtype=np.intp),
        torque_values=torque_values,
        null_values=null_values,
        n_edges=n,
    )
    return DualSolution(solution, y, scale[A.shape[0] :])
