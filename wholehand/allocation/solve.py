"""Solving the allocation QP: constraint screening and the warm start between cycles.

The solvers themselves are adapters in :mod:`wholehand.allocation.solvers`.

Constraint screening (exact). The torque and consistency rows (``n_a + dim Null(J_act^T)``
two-sided rows, ~120 at 45 contacts) are rarely binding, yet a dense solver pays for every row in
its setup. :func:`solve_allocation` solves with a working subset of them (always all
bounds, the wrench equality and the minimum squeeze), evaluates every left-out row at the
solution in O(m n) without forming it, adds the violated ones and solves again. The relaxed
optimum is a lower bound of the full one, so once it violates no row it is optimal for the full
problem. Rows are only ever added, so it terminates; after ``max_rounds`` the full problem is
solved instead.

Warm start (:class:`WarmStart`, driven by the allocator). The torque rows binding last cycle (by
joint) and, when the contacts sit on the same links in the same order, the consistency rows
binding last cycle (by basis index) seed the working set, which saves screening rounds. Solvers
that use a primal start (OSQP, qpsolvers) get the previous edge weights, each contact matched to
the previous contact on the same link with the nearest point (within ``match_radius``). DAQP
instead restarts from its own previous working set. Measured effect (``wholehand bench
allocate``): large where rows bind (fewer rounds) and for OSQP; none for PIQP (interior point).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from wholehand.allocation.problem import N_WRENCH, AllocationQP
from wholehand.allocation.solvers import QPSolver
from wholehand.allocation.solvers.base import DenseQP, QPResult

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

SCREEN_TOL: float = 1e-9
"""A left-out row violated by more than this is added to the working set [N or N*m]."""

FEAS_TOL: float = 1e-5
"""Largest constraint violation of an accepted solution [N or N*m]; beyond it: solver failure."""

MATCH_RADIUS: float = 0.005
"""Contacts on the same link closer than this across cycles are the same contact [m]."""


# ------------------------------------------------------------------------------------------------
# Warm start
# ------------------------------------------------------------------------------------------------


@dataclass
class WarmStart:
    """What one cycle leaves for the next: solution and binding rows, keyed by contact identity."""

    match_radius: float = MATCH_RADIUS
    """Same link and closer than this [m]: the same contact."""
    p_world: FloatArray | None = None
    """(N, 3) previous contact points [m]."""
    link: IntArray | None = None
    """(N,) previous contact links."""
    lam: FloatArray | None = None
    """(N, 4) previous edge weights [N]."""
    torque_dofs: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    """Joint indices whose torque rows were binding."""
    null_rows: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    """Consistency-row indices that were binding."""

    def clear(self) -> None:
        """Forget everything."""
        self.p_world = self.link = self.lam = None
        self.torque_dofs = np.zeros(0, dtype=np.intp)
        self.null_rows = np.zeros(0, dtype=np.intp)

    def match(self, p_world: FloatArray, link: IntArray) -> IntArray:
        """(N,) index of the previous contact each current one continues, -1 for new ones."""
        n = link.size
        if self.p_world is None or self.link is None or self.link.size == 0:
            return np.full(n, -1, dtype=np.intp)
        r2 = self.match_radius**2
        if self.link.size == n and np.array_equal(self.link, link):
            # Fast path: same contacts in the same order, each still within the radius.
            d = p_world - self.p_world
            if np.einsum("ij,ij->i", d, d).max() <= r2:
                return np.arange(n, dtype=np.intp)
        q = self.p_world
        d2 = (
            np.einsum("ij,ij->i", p_world, p_world)[:, None]
            + np.einsum("ij,ij->i", q, q)[None, :]
            - 2.0 * (p_world @ q.T)
        )
        d2 = np.where(link[:, None] == self.link[None, :], d2, np.inf)
        j = np.argmin(d2, axis=1)
        ok = d2[np.arange(n), j] <= r2
        return np.where(ok, j, -1).astype(np.intp)

    def add_rows(self, torque_dofs: IntArray, null_rows: IntArray) -> None:
        """Seed the next cycle with these rows too (a cycle that ran out of time found them
        violated); the consistency rows only count while the contacts stay on the same links."""
        self.torque_dofs = np.union1d(self.torque_dofs, torque_dofs).astype(np.intp)
        self.null_rows = np.union1d(self.null_rows, null_rows).astype(np.intp)

    def same_links(self, link: IntArray) -> bool:
        """True when the contacts sit on the same links, in the same order, as last cycle."""
        return self.link is not None and np.array_equal(self.link, link)


# ------------------------------------------------------------------------------------------------
# Screening loop
# ------------------------------------------------------------------------------------------------


@dataclass
class AllocationSolution:
    """Outcome of :func:`solve_allocation`."""

    x: FloatArray | None
    """(4N + 6,) ``[lambda; w]``, None on failure."""
    status: str
    """``"optimal"``, ``"infeasible"`` or ``"failed"``."""
    rounds: int
    """Solves performed (1 without screening)."""
    n_rows: int
    """Torque and consistency rows in the last solve."""
    iterations: int
    """Solver iterations, summed over rounds."""
    violation: float
    """Largest constraint violation of ``x`` over the full problem [N or N*m] (inf if none)."""
    detail: str = ""
    """Solver status text of the last solve."""
    torque_sel: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    """Positions in ``qp.torque_rows`` of the torque rows in the last solve."""
    null_sel: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    """Consistency rows in the last solve."""
    torque_values: FloatArray = field(default_factory=lambda: np.zeros(0))
    """(n_t,) torques of every torque row at ``x`` [N*m] (``qp.T_lam @ lambda``)."""
    null_values: FloatArray = field(default_factory=lambda: np.zeros(0))
    """(n_null,) every consistency value ``N_u^T f_act`` at ``x`` [N]."""


def dense_qp(qp: AllocationQP, torque_sel: IntArray, null_sel: IntArray) -> DenseQP:
    """The solved form restricted to the selected torque rows and consistency rows."""
    nl, n = qp.n_lambda, qp.n_x
    nt, nn = torque_sel.size, null_sel.size
    m = N_WRENCH + 1 + nt + nn
    A = np.zeros((m, n))
    A[:N_WRENCH, :nl] = qp.G_lam
    A[:N_WRENCH, nl:] = -np.eye(N_WRENCH)
    A[N_WRENCH, :nl] = 1.0
    k = N_WRENCH + 1
    lim = np.empty(nt + nn)
    if nt:
        A[k : k + nt, :nl] = qp.T_lam[torque_sel]
        lim[:nt] = qp.tau_max[qp.torque_rows[torque_sel]]
    if nn:
        A[k + nt :, :nl] = qp.null_rows(null_sel)
        lim[nt:] = qp.params.eps_margin
    # G lambda - w = -w_ext: w is then the net wrench G f + w_ext, whose norm is minimised.
    lower = np.concatenate((-qp.w_ext, [qp.params.f_n_min], -lim))
    upper = np.concatenate((-qp.w_ext, [np.inf], lim))
    p_diag = np.concatenate((np.full(nl, qp.params.reg), np.ones(N_WRENCH)))
    lb = np.concatenate((np.zeros(nl), np.full(N_WRENCH, -np.inf)))
    return DenseQP(p_diag, A, lower, upper, N_WRENCH, lb, np.full(n, np.inf))


def solve_allocation(
    qp: AllocationQP,
    solver: QPSolver,
    *,
    x0: FloatArray | None = None,
    warm: bool = False,
    torque_sel: IntArray | None = None,
    null_sel: IntArray | None = None,
    screening: bool = True,
    screen_tol: float = SCREEN_TOL,
    max_rounds: int = 8,
    deadline_ns: int | None = None,
) -> AllocationSolution:
    """Solve the allocation QP, screening the torque and consistency rows.

    Args:
        qp: The cycle's problem.
        solver: Solver adapter.
        x0: (4N + 6,) primal start, or None.
        warm: The problem continues the previous cycle's (solvers keeping state may use it).
        torque_sel: Initial torque rows (positions in ``qp.torque_rows``), or None for none.
        null_sel: Initial consistency rows, or None for none.
        screening: False: solve once with every row (reference behaviour).
        screen_tol: Violation beyond which a left-out row is added [N or N*m].
        max_rounds: Solves before falling back to the full problem.
        deadline_ns: ``time.perf_counter_ns()`` at which solving stops: each solve gets the
            time left as its limit (solvers that are :attr:`~QPSolver.time_limited` stop
            themselves near it, others finish their solve), and no solve starts past it. A
            stopped solve, or a solution that still violates a left-out row once the time is
            up, ends with status ``"deadline"`` and no x. None: no deadline.
    """
    all_t = np.arange(qp.torque_rows.size, dtype=np.intp)
    eps = qp.params.eps_margin
    n_null = qp.n_null if np.isfinite(eps) else 0
    all_n = np.arange(n_null, dtype=np.intp)
    t_mask = np.zeros(all_t.size, bool)
    n_mask = np.zeros(n_null, bool)
    if not screening:
        t_mask[:] = True
        n_mask[:] = True
    else:
        if torque_sel is not None:
            t_mask[torque_sel[torque_sel < all_t.size]] = True
        if null_sel is not None:
            n_mask[null_sel[null_sel < n_null]] = True
    t_in, n_in = np.flatnonzero(t_mask), np.flatnonzero(n_mask)
    limits = qp.tau_max[qp.torque_rows]
    rounds = iterations = 0
    res = QPResult(None, "failed")
    while True:
        time_limit = None
        if deadline_ns is not None:
            time_limit = (deadline_ns - time.perf_counter_ns()) * 1e-9
            if time_limit <= 0.0:
                return _deadline(rounds, t_in.size + n_in.size, iterations, t_in, n_in)
        rounds += 1
        full = rounds > max_rounds
        if full:
            t_in, n_in = all_t, all_n
        res = solver.solve(
            dense_qp(qp, t_in, n_in),
            x0 if solver.primal_warm_start else None,
            warm=warm or x0 is not None,
            time_limit=time_limit,
        )
        iterations += res.iterations
        if res.status == "deadline":
            return _deadline(rounds, t_in.size + n_in.size, iterations, t_in, n_in)
        if res.x is None or not np.all(np.isfinite(res.x)):
            return AllocationSolution(
                x=None,
                status=res.status if res.x is None else "failed",
                rounds=rounds,
                n_rows=t_in.size + n_in.size,
                iterations=iterations,
                violation=np.inf,
                detail=res.detail,
                torque_sel=t_in,
                null_sel=n_in,
            )
        lam = res.x[: qp.n_lambda]
        t_val = qp.T_lam @ lam
        t_over = np.abs(t_val) - limits
        if n_null:
            z_val = qp.null_values(lam)
            z_over = np.abs(z_val) - eps
        else:
            z_val = z_over = np.zeros(0)
        if full or (t_in.size == all_t.size and n_in.size == n_null):
            break
        add_t = np.flatnonzero((t_over > screen_tol) & ~t_mask)
        add_n = np.flatnonzero((z_over > screen_tol) & ~n_mask)
        if add_t.size == 0 and add_n.size == 0:
            break
        t_mask[add_t] = True
        n_mask[add_n] = True
        t_in, n_in = np.flatnonzero(t_mask), np.flatnonzero(n_mask)
        x0, warm = res.x, True
    viol = max(
        0.0,
        -lam.min(),
        qp.params.f_n_min - lam.sum(),
        t_over.max(initial=0.0),
        z_over.max(initial=0.0),
    )
    return AllocationSolution(
        x=res.x,
        status="optimal",
        rounds=rounds,
        n_rows=t_in.size + n_in.size,
        iterations=iterations,
        violation=float(viol),
        detail=res.detail,
        torque_sel=t_in,
        null_sel=n_in,
        torque_values=t_val,
        null_values=z_val,
    )


def _deadline(
    rounds: int, n_rows: int, iterations: int, torque_sel: IntArray, null_sel: IntArray
) -> AllocationSolution:
    return AllocationSolution(
        x=None,
        status="deadline",
        rounds=rounds,
        n_rows=n_rows,
        iterations=iterations,
        violation=np.inf,
        detail="deadline passed before the solution was exact",
        torque_sel=torque_sel,
        null_sel=null_sel,
    )


def binding_rows(
    qp: AllocationQP, sol: AllocationSolution, rel: float = 1e-6, abs_tol: float = 1e-9
) -> tuple[IntArray, IntArray]:
    """(positions in ``qp.torque_rows``, consistency-row indices) at their bounds in ``sol``."""
    lim = qp.tau_max[qp.torque_rows]
    t = np.flatnonzero(np.abs(sol.torque_values) >= lim * (1.0 - rel) - abs_tol)
    eps = qp.params.eps_margin
    z = np.flatnonzero(np.abs(sol.null_values) >= eps * (1.0 - rel) - abs_tol)
    return t, z


__all__ = [
    "FEAS_TOL",
    "MATCH_RADIUS",
    "SCREEN_TOL",
    "AllocationSolution",
    "WarmStart",
    "binding_rows",
    "dense_qp",
    "solve_allocation",
]
