"""Solving the allocation QP: screening the rows and the edge weights.

The solvers themselves are adapters in :mod:`wholehand.allocation.solvers`.

Constraint screening (exact). The torque and consistency rows (``n_a + dim Null(J_act^T)``
two-sided rows, ~120 at 45 contacts) are rarely binding, yet a dense solver pays for every row in
its setup. :func:`solve_allocation` solves with a working subset of them (always all
bounds, the wrench equality and the minimum squeeze), evaluates every left-out row at the
solution in O(m n) without forming it, adds the violated ones and solves again. The relaxed
optimum is a lower bound of the full one, so once it violates no row it is optimal for the full
problem. Rows are only ever added, so it terminates; after ``max_rounds`` the full problem is
solved instead.

Edge screening (exact, ``edge_sel``; the allocator's ``screen_edges``). Near a loss most edge
weights are zero at the optimum (over three in four in the tests' recorded cycle), and a dense
active-set solver pays for each of them with an iteration and a factorisation update. With a solver
that reports multipliers (DAQP), the edge weights are screened like the rows: the problem holds a
working subset of them as variables, the others at zero. A left-out ``lambda_j`` could lower the
objective only if its bound would need a multiplier of the wrong sign: stationarity of the full
problem reads ``A_j^T y + z_j = 0`` (``A_j`` its column in the rows, ``y`` the rows' multipliers
from the sub-problem), and a lower bound needs ``z_j <= 0``, so edges with ``A_j^T y < 0`` join the
next round. When no row is violated and no edge prices negative, the sub-problem's solution with
the left-out edges at zero satisfies the full problem's KKT conditions. A sub-problem made
infeasible by the missing edges is solved again with all of them. Each round then starts from the
active set of the round before (:class:`ActiveSet`), mapped by identity onto the larger problem.

The warm start between cycles is :mod:`wholehand.allocation.warm_start`.
"""

from __future__ import annotations

import functools
import time
from typing import Any

import numpy as np
import numpy.typing as npt

from wholehand.allocation.problem import N_WRENCH, AllocationQP
from wholehand.allocation.screening_kernels import (
    at_bounds,
    priced_edges,
    rows_over,
    selection,
    solved_rows,
)
from wholehand.allocation.solution import ActiveSet, AllocationSolution
from wholehand.allocation.solvers import QPSolver
from wholehand.allocation.solvers.base import DenseQP, QPResult

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

SCREEN_TOL: float = 1e-9
"""A left-out row violated by more than this is added to the working set [N or N*m]."""

_NONE = np.zeros(0, dtype=np.intp)

FEAS_TOL: float = 1e-4
"""Largest relative constraint violation of an accepted solution [-]
(:attr:`AllocationSolution.relative_violation`: a torque row's excess over its own limit, a
force constraint's over the allocation's force scale); beyond it the answer is inaccurate."""

# ------------------------------------------------------------------------------------------------
# Screening loop
# ------------------------------------------------------------------------------------------------


def dense_qp(
    qp: AllocationQP,
    torque_sel: IntArray,
    null_sel: IntArray,
    edge_sel: IntArray | None = None,
    guess: ActiveSet | None = None,
) -> DenseQP:
    """The solved form restricted to the selected torque rows and consistency rows, and to the
    selected edge weights (``edge_sel``, indices into ``lambda``; None: all of them): the
    variables are then ``[lambda[edge_sel]; w]``, the others held at zero. ``guess``: the
    active set to start from."""
    null = qp.null_rows(null_sel)
    return _round_problem(qp, null, qp.torque_bounds(), torque_sel, null_sel, edge_sel, guess)


def _round_problem(
    qp: AllocationQP,
    null: FloatArray,
    torque_bounds: tuple[FloatArray, FloatArray],
    torque_sel: IntArray,
    null_sel: IntArray,
    edge_sel: IntArray | None,
    guess: ActiveSet | None,
) -> DenseQP:
    """The problem of one screening round, from the selected consistency rows ``null`` and
    the bounds of every torque row."""
    edges = np.arange(qp.n_lambda, dtype=np.intp) if edge_sel is None else edge_sel
    # G lambda - w = -w_ext: w is then the net wrench G f + w_ext, whose norm is minimised.
    A, lower, upper = solved_rows(
        qp.G_lam,
        qp.T_lam,
        torque_sel,
        null,
        qp.w_ext,
        qp.params.f_n_min,
        *torque_bounds,
        qp.params.eps_margin,
        edges,
    )
    p_diag, lb, ub = _variable_terms(edges.size, qp.params.reg)
    active = None if guess is None else guess.vector(torque_sel, null_sel, edges)
    return DenseQP(p_diag, A, lower, upper, N_WRENCH, lb, ub, active)


@functools.lru_cache(maxsize=256)
def _variable_terms(n_edges: int, reg: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Hessian diagonal and variable bounds of ``[lambda (n_edges); w (6)]`` (read-only; a
    problem's size recurs from cycle to cycle)."""
    p_diag = np.concatenate((np.full(n_edges, reg), np.ones(N_WRENCH)))
    lb = np.concatenate((np.zeros(n_edges), np.full(N_WRENCH, -np.inf)))
    ub = np.full(n_edges + N_WRENCH, np.inf)
    for a in (p_diag, lb, ub):
        a.setflags(write=False)
    return p_diag, lb, ub


@functools.lru_cache(maxsize=256)
def _uniform(n: int, value: float) -> FloatArray:
    """(n,) read-only array of ``value``: the consistency rows' common bound (a problem's size
    recurs from cycle to cycle, and ``np.full`` costs microseconds in a cycle)."""
    out = np.full(n, value)
    out.setflags(write=False)
    return out


def solve_allocation(
    qp: AllocationQP,
    solver: QPSolver,
    *,
    x0: FloatArray | None = None,
    warm: bool = False,
    torque_sel: IntArray | None = None,
    null_sel: IntArray | None = None,
    edge_sel: IntArray | None = None,
    screening: bool = True,
    screen_tol: float = SCREEN_TOL,
    max_rounds: int = 8,
    deadline_ns: int | None = None,
) -> AllocationSolution:
    """Solve the allocation QP, screening the torque and consistency rows and the edge weights.

    Args:
        qp: The cycle's problem.
        solver: Solver adapter.
        x0: (4N + 6,) primal start, or None.
        warm: The problem continues the previous cycle's (solvers keeping state may use it).
        torque_sel: Initial torque rows (positions in ``qp.torque_rows``), or None for none.
        null_sel: Initial consistency rows, or None for none.
        edge_sel: Screen the edge weights too, starting from these (indices into
            ``lambda``), with solvers that :attr:`~QPSolver.reports_duals`; each screening round
            then also starts from the active set of the round before. None (or empty): every
            edge weight, every round from the solver's own warm start.
        screening: False: solve once with every row and every edge weight (reference).
        screen_tol: Violation beyond which a left-out row is added [N or N*m], and the
            multiplier of a left-out edge weight's bound beyond which it is added.
        max_rounds: Solves before falling back to the full problem.
        deadline_ns: ``time.perf_counter_ns()`` at which solving stops: each solve gets the
            time left as its limit (solvers that are :attr:`~QPSolver.time_limited` stop
            themselves near it, others finish their solve), and no round starts (nor is its
            problem built) past it. A stopped solve, or a solution that still violates a
            left-out row once the time is up, ends with status ``"deadline"`` and no x. None:
            no deadline.
    """
    screen_edges = screening and edge_sel is not None and edge_sel.size > 0 and solver.reports_duals
    ws = _WorkingSet(qp, torque_sel, null_sel, edge_sel if screen_edges else None, screening)
    torque_bounds = qp.torque_bounds()
    while True:
        if _past(deadline_ns):
            # Past it already: not even the next round's problem is built.
            return ws.deadline()
        full = ws.next_round(max_rounds)
        e_in = ws.edges_in()
        start = _round_start(x0, e_in, qp.n_lambda) if solver.primal_warm_start else None
        null = qp.null_rows(ws.n_in)
        problem = _round_problem(qp, null, torque_bounds, ws.t_in, ws.n_in, e_in, ws.guess)
        time_limit = _time_left(deadline_ns)  # once the problem is built
        if time_limit is not None and time_limit <= 0.0:
            ws.rounds -= 1  # this round never solved
            return ws.deadline()
        res = ws.solve(solver, problem, start, warm or x0 is not None, time_limit)
        if res.status == "infeasible" and e_in is not None:
            ws.e_mask = None  # infeasible with some edges held at zero: try them all
            continue
        unsolved = ws.unsolved(res)
        if unsolved is not None:
            return unsolved
        assert res.x is not None
        x = _full_x(qp, res.x, e_in)
        add_t, add_n = ws.evaluate_rows(x, screen_tol)
        if full or not ws.widen(res, e_in, null, add_t, add_n, screen_tol, screen_edges):
            break
        x0, warm = x, True
    return ws.optimal(x, res.detail)


class _WorkingSet:
    """The rows and edge weights of the screening rounds so far, their tallies, and the values
    of every row at the last round's solution."""

    def __init__(
        self,
        qp: AllocationQP,
        torque_sel: IntArray | None,
        null_sel: IntArray | None,
        edge_sel: IntArray | None,
        screening: bool,
    ) -> None:
        self.qp = qp
        eps = qp.params.eps_margin
        self.n_null = qp.n_null if np.isfinite(eps) else 0
        self.all_t = np.arange(qp.torque_rows.size, dtype=np.intp)
        self.all_n = np.arange(self.n_null, dtype=np.intp)
        self.t_mask, self.t_in = _first_rows(torque_sel, self.all_t, screening)
        self.n_mask, self.n_in = _first_rows(null_sel, self.all_n, screening)
        self.e_mask: BoolArray | None = (
            None if edge_sel is None else _first_edges(edge_sel, qp.n_lambda)
        )
        """The edge weights in the problem, when screened (None: all of them)."""
        self.eps_limits = _uniform(self.n_null, eps)
        self.guess: ActiveSet | None = None
        self.rounds = self.iterations = self.solver_ns = 0
        self.x_relaxed: FloatArray | None = None
        """The last round's solution, for a deadline."""
        self.t_val = self.z_val = np.zeros(0)
        """Every torque and consistency row's value at :attr:`x_relaxed`."""
        self.z_worst = 0.0

    def next_round(self, max_rounds: int) -> bool:
        """Count a round; past ``max_rounds``, the fallback to the full problem (every row,
        every edge weight), and True."""
        self.rounds += 1
        if self.rounds <= max_rounds:
            return False
        self.t_in, self.n_in = self.all_t, self.all_n
        self.e_mask = None
        return True

    def edges_in(self) -> IntArray | None:
        """The edge weights of this round's problem, or None for all of them."""
        if self.e_mask is None or self.e_mask.all():
            return None
        return np.flatnonzero(self.e_mask)

    def solve(
        self,
        solver: QPSolver,
        problem: DenseQP,
        start: FloatArray | None,
        warm: bool,
        time_limit: float | None,
    ) -> QPResult:
        """One round's solve, its time and iterations tallied."""
        started = time.perf_counter_ns()
        res = solver.solve(problem, start, warm=warm, time_limit=time_limit)
        self.solver_ns += time.perf_counter_ns() - started
        self.iterations += res.iterations
        return res

    def evaluate_rows(self, x: FloatArray, screen_tol: float) -> tuple[IntArray, IntArray]:
        """Every row's value at the round's solution ``x``, and the left-out torque and
        consistency rows it violates."""
        self.x_relaxed = x
        lam = x[: self.qp.n_lambda]
        self.t_val = self.qp.T_lam @ lam
        totals = self.qp.torque_totals(self.t_val)
        add_t, _ = rows_over(totals, self.qp.torque_limits, self.t_mask, screen_tol)
        self.z_val = self.qp.null_values(lam) if self.n_null else np.zeros(0)
        add_n, self.z_worst = rows_over(self.z_val, self.eps_limits, self.n_mask, screen_tol)
        return add_t, add_n

    def widen(
        self,
        res: QPResult,
        e_in: IntArray | None,
        null: FloatArray,
        add_t: IntArray,
        add_n: IntArray,
        screen_tol: float,
        guess: bool,
    ) -> bool:
        """Add the violated rows ``add_t``, ``add_n`` and the edge weights that price negative
        at the round's multipliers to the next round's problem; False when there are none
        (the round's solution is optimal). ``guess``: the next round starts from this round's
        active set."""
        add_e = _NONE
        if e_in is not None:
            assert self.e_mask is not None
            add_e = _edges_to_add(
                self.qp, res.duals, e_in, self.e_mask, self.t_in, null, screen_tol
            )
        if add_t.size == 0 and add_n.size == 0 and add_e.size == 0:
            return False
        if guess and res.duals is not None:
            self.guess = ActiveSet.of(self.qp, res.duals, self.t_in, self.n_in, e_in)
        self.t_mask[add_t] = True
        self.n_mask[add_n] = True
        if self.e_mask is not None:
            self.e_mask[add_e] = True
        self.t_in, self.n_in = np.flatnonzero(self.t_mask), np.flatnonzero(self.n_mask)
        return True

    def optimal(self, x: FloatArray, detail: str) -> AllocationSolution:
        """The solution of a round that violates no left-out row (or of the full problem)."""
        viol, rel = violations(self.qp, x[: self.qp.n_lambda], self.t_val, self.z_worst)
        return self._outcome(
            x,
            "optimal",
            detail,
            violation=viol,
            relative_violation=rel,
            torque_values=self.t_val,
            null_values=self.z_val,
            n_edges=self.qp.n_lambda if self.e_mask is None else int(self.e_mask.sum()),
        )

    def unsolved(self, res: QPResult) -> AllocationSolution | None:
        """The outcome of a round whose solver was stopped by the deadline, returned no x, or
        a non-finite one; None when it solved."""
        if res.status == "deadline":
            return self.deadline()
        if res.x is not None and np.isfinite(res.x).all():
            return None
        return self._outcome(None, res.status if res.x is None else "failed", res.detail)

    def deadline(self) -> AllocationSolution:
        """The outcome of a solve stopped by its deadline; the row values are those at
        :attr:`x_relaxed` (empty without it)."""
        return self._outcome(
            None,
            "deadline",
            "deadline passed before the solution was exact",
            torque_values=self.t_val,
            null_values=self.z_val,
            x_relaxed=self.x_relaxed,
        )

    def _outcome(
        self,
        x: FloatArray | None,
        status: str,
        detail: str,
        violation: float = np.inf,
        **more: Any,
    ) -> AllocationSolution:
        """An outcome with the rounds' tallies and last selections, and the fields ``more``."""
        return AllocationSolution(
            x=x,
            status=status,
            rounds=self.rounds,
            n_rows=self.t_in.size + self.n_in.size,
            iterations=self.iterations,
            violation=violation,
            detail=detail,
            solver_time=self.solver_ns * 1e-9,
            torque_sel=self.t_in,
            null_sel=self.n_in,
            **more,
        )


def _past(deadline_ns: int | None) -> bool:
    """Whether ``time.perf_counter_ns()`` has reached the deadline (never, without one)."""
    return deadline_ns is not None and time.perf_counter_ns() >= deadline_ns


def _time_left(deadline_ns: int | None) -> float | None:
    """Seconds until the deadline (negative past it), or None without one."""
    if deadline_ns is None:
        return None
    return (deadline_ns - time.perf_counter_ns()) * 1e-9


def _round_start(x0: FloatArray | None, e_in: IntArray | None, n_lambda: int) -> FloatArray | None:
    """The round's primal start: ``x0`` restricted to the round's edge weights ``e_in``."""
    if x0 is None or e_in is None:
        return x0
    return np.concatenate((x0[e_in], x0[n_lambda:]))


def _first_rows(
    chosen: IntArray | None, every: IntArray, screening: bool
) -> tuple[BoolArray, IntArray]:
    """Mask and positions of the rows the first round has: ``chosen`` (None: none) when
    screening, else ``every`` row."""
    if not screening:
        return np.ones(every.size, bool), every
    return selection(_NONE if chosen is None else chosen, every.size)


def _first_edges(edge_sel: IntArray | None, n_lambda: int) -> BoolArray:
    """Mask of the edge weights the first round has (those of ``edge_sel`` in range)."""
    mask = np.zeros(n_lambda, bool)
    if edge_sel is not None:
        mask[edge_sel[edge_sel < n_lambda]] = True
    return mask


def _full_x(qp: AllocationQP, x_round: FloatArray, e_in: IntArray | None) -> FloatArray:
    """(4N + 6,) the round's solution with the left-out edge weights (zero) put back."""
    if e_in is None:
        return x_round
    nl = qp.n_lambda
    x = np.zeros(qp.n_x)
    x[e_in] = x_round[: e_in.size]
    x[nl:] = x_round[e_in.size :]
    return x


def _edges_to_add(
    qp: AllocationQP,
    duals: FloatArray | None,
    e_in: IntArray,
    e_mask: BoolArray,
    t_in: IntArray,
    null: FloatArray,
    screen_tol: float,
) -> IntArray:
    """The left-out edge weights the next round adds: those whose bound's multiplier would
    be needed (module docstring); every one when the solver gave no multipliers."""
    if duals is None:
        return np.flatnonzero(~e_mask)
    y = duals[e_in.size + N_WRENCH :]
    return priced_edges(qp.G_lam, qp.T_lam, t_in, null, y, e_mask, screen_tol)


def violations(
    qp: AllocationQP, lam: FloatArray, torque_values: FloatArray, null_worst: float
) -> tuple[float, float]:
    """The largest constraint violation at ``lambda`` [N or N*m] and the largest relative one
    [-] (:attr:`AllocationSolution.relative_violation`), from the torque rows' values and the
    consistency rows' worst excess."""
    total = float(lam.sum())
    force_scale = max(qp.params.f_n_min, total, np.finfo(float).tiny)
    force_worst = max(0.0, -float(lam.min()), qp.params.f_n_min - total, null_worst)
    torque_worst = torque_relative = 0.0
    if torque_values.size:
        excess = np.abs(qp.torque_totals(torque_values)) - qp.torque_limits
        torque_worst = float(excess.max())
        torque_relative = float((excess / qp.torque_limits).max())
    worst = max(force_worst, torque_worst)
    relative = max(force_worst / force_scale, torque_relative)
    if not (np.isfinite(worst) and np.isfinite(relative)):
        return np.inf, np.inf
    return worst, relative


def binding_rows(
    qp: AllocationQP, sol: AllocationSolution, rel: float = 1e-6, abs_tol: float = 1e-9
) -> tuple[IntArray, IntArray]:
    """(positions in ``qp.torque_rows``, consistency-row indices) at their bounds in ``sol``."""
    return rows_at_bounds(qp, sol.torque_values, sol.null_values, rel, abs_tol)


def rows_at_bounds(
    qp: AllocationQP,
    torque_values: FloatArray,
    null_values: FloatArray,
    rel: float = 1e-6,
    abs_tol: float = 1e-9,
) -> tuple[IntArray, IntArray]:
    """(positions in ``qp.torque_rows``, consistency-row indices) whose values (every torque
    row's ``T_lam @ lambda`` [N*m], every consistency row's [N]) are at or past their bounds."""
    t = at_bounds(qp.torque_totals(torque_values), qp.torque_limits, rel, abs_tol)
    eps = _uniform(null_values.size, qp.params.eps_margin)
    return t, at_bounds(np.ascontiguousarray(null_values), eps, rel, abs_tol)


__all__ = [
    "FEAS_TOL",
    "violations",
    "ActiveSet",
    "SCREEN_TOL",
    "AllocationSolution",
    "binding_rows",
    "rows_at_bounds",
    "dense_qp",
    "solve_allocation",
]
