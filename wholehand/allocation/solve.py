"""Solving the allocation QP: solver registry and adapters, constraint screening, warm start.

Solvers are named by a string. ``"daqp"``, ``"osqp"`` and ``"piqp"`` are driven through their own
Python APIs: a persistent DAQP model per problem shape, OSQP without the wrapper's conversions,
PIQP's sparse KKT solver (the qpsolvers wrappers add per-cycle conversions; ``wholehand bench
allocate`` compares them). Any other name in ``qpsolvers.available_solvers``, and
``"qpsolvers:<name>"`` for any of them, goes through :func:`qpsolvers.solve_problem`.
:func:`available_solvers` lists what is installed; an unknown name raises :class:`ConfigError`.

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

import abc
import time
import warnings
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from wholehand.allocation.problem import N_WRENCH, AllocationQP
from wholehand.errors import ConfigError

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

BIG: float = 1e30
"""Stand-in for infinite bounds in solvers that want finite numbers."""

SCREEN_TOL: float = 1e-9
"""A left-out row violated by more than this is added to the working set [N or N*m]."""

FEAS_TOL: float = 1e-5
"""Largest constraint violation of an accepted solution [N or N*m]; beyond it: solver failure."""

MATCH_RADIUS: float = 0.005
"""Contacts on the same link closer than this across cycles are the same contact [m]."""


# ------------------------------------------------------------------------------------------------
# Canonical dense QP handed to the adapters
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class DenseQP:
    """``min 1/2 x^T diag(p) x`` s.t. ``lower <= A x <= upper``, ``lb <= x <= ub``.

    The first ``n_eq`` rows are equalities (``lower == upper``). Infinite bounds are ``+-inf``.
    """

    p_diag: FloatArray
    """(n,) diagonal of the Hessian (> 0)."""
    A: FloatArray
    """(m, n) constraint rows."""
    lower: FloatArray
    """(m,) row lower bounds."""
    upper: FloatArray
    """(m,) row upper bounds."""
    n_eq: int
    """Number of leading equality rows."""
    lb: FloatArray
    """(n,) variable lower bounds."""
    ub: FloatArray
    """(n,) variable upper bounds."""


@dataclass
class QPResult:
    """What an adapter returns."""

    x: FloatArray | None
    """(n,) primal solution, None when none was found."""
    status: str
    """``"optimal"``, ``"infeasible"`` or ``"failed"``."""
    iterations: int = 0
    """Solver iterations."""
    detail: str = ""
    """Solver-specific status text."""
    raw: Any = None
    """The solver's own result object, for debugging."""


class QPSolver(abc.ABC):
    """Adapter from :class:`DenseQP` to one solver."""

    name: ClassVar[str] = ""
    """Registry name."""
    defaults: ClassVar[Mapping[str, Any]] = {}
    """Settings used unless overridden: tight enough for exact-looking allocations."""
    primal_warm_start: ClassVar[bool] = True
    """Whether the solver uses the values of a primal start ``x0``."""

    def __init__(self, settings: Mapping[str, Any] | None = None) -> None:
        self.settings: dict[str, Any] = {**self.defaults, **(settings or {})}

    def solve(self, qp: DenseQP, x0: FloatArray | None = None, warm: bool = False) -> QPResult:
        """Solve ``qp``; never raises (a solver exception becomes status ``"failed"``).

        Args:
            qp: The problem.
            x0: (n,) primal start, used by solvers with :attr:`primal_warm_start`.
            warm: ``qp`` continues the previous solve (next control cycle, or the next screening
                round): solvers that keep state (DAQP's working set) may start from it.
        """
        try:
            return self._solve(qp, x0, warm)
        except Exception as err:  # the control loop must not raise on a solver error
            self.reset()
            return QPResult(None, "failed", 0, f"{type(err).__name__}: {err}", err)

    @abc.abstractmethod
    def _solve(self, qp: DenseQP, x0: FloatArray | None, warm: bool) -> QPResult:
        """Solver-specific :meth:`solve`; may raise."""

    def reset(self) -> None:  # noqa: B027 - optional hook
        """Forget state kept between solves (persistent solver objects)."""

    def probe(self, owner: str = "QPSolver") -> None:
        """Solve a 2-variable QP once, so that bad settings fail at construction.

        Raises:
            ConfigError: The solver raised (typically: an unknown or invalid setting).
        """
        qp = DenseQP(
            p_diag=np.ones(2),
            A=np.array([[1.0, 1.0]]),
            lower=np.array([1.0]),
            upper=np.array([np.inf]),
            n_eq=0,
            lb=np.zeros(2),
            ub=np.full(2, np.inf),
        )
        try:
            self._solve(qp, None, False)
        except Exception as err:
            raise ConfigError(
                f"{owner}: solver {self.name!r} rejected solver_settings={self.settings!r}: "
                f"{type(err).__name__}: {err}"
            ) from err
        finally:
            self.reset()


class DaqpSolver(QPSolver):
    """DAQP (dual active set, dense; Arnström et al. 2022) through its own API.

    One ``daqp.Model`` is kept per problem shape ``(n, m)``, so the Hessian is processed once
    and each cycle only updates ``A`` and the bounds. A warm solve (``warm``, same shape as the
    previous solve) starts from the previous solve's working set; if it fails, the problem is
    solved again from scratch. The values of ``x0`` are not used.
    """

    name = "daqp"
    defaults: ClassVar[Mapping[str, Any]] = {"primal_tol": 1e-9, "iter_limit": 2000}
    primal_warm_start = False
    max_models: ClassVar[int] = 8
    """Problem shapes kept (least recently used dropped first)."""

    def __init__(self, settings: Mapping[str, Any] | None = None) -> None:
        import daqp  # noqa: F401  (fail at construction when missing)

        super().__init__(settings)
        self._models: OrderedDict[tuple[int, int, int], tuple[Any, FloatArray]] = OrderedDict()
        self._last_key: tuple[int, int, int] | None = None

    def reset(self) -> None:
        """Drop the kept models (and with them the warm-start state)."""
        self._models.clear()
        self._last_key = None

    def _solve(self, qp: DenseQP, x0: FloatArray | None, warm: bool) -> QPResult:
        import daqp

        n = qp.p_diag.size
        key = (n, qp.A.shape[0], qp.n_eq)
        bu = np.minimum(np.concatenate((qp.ub, qp.upper)), BIG)
        bl = np.maximum(np.concatenate((qp.lb, qp.lower)), -BIG)
        sense = np.zeros(bu.size, dtype=np.intc)
        sense[n : n + qp.n_eq] = 5  # active + immutable: equality
        entry = self._models.get(key)
        warm = warm and key == self._last_key and entry is not None
        if entry is None or not np.array_equal(entry[1], qp.p_diag):
            model = daqp.Model()
            unknown = set(self.settings) - set(model.settings)
            if unknown:
                raise ValueError(
                    f"unknown DAQP settings {sorted(unknown)}; known: {sorted(model.settings)}"
                )
            model.settings = dict(self.settings)
            model.setup(np.diag(qp.p_diag), np.zeros(n), qp.A, bu, bl, sense)
            self._models[key] = (model, qp.p_diag.copy())
            warm = False
        else:
            model = entry[0]
            self._models.move_to_end(key)
            if warm:
                model.update(A=qp.A, bupper=bu, blower=bl)
            else:
                model.update(A=qp.A, bupper=bu, blower=bl, sense=sense)
        while len(self._models) > self.max_models:
            self._models.popitem(last=False)
        self._last_key = key
        x, _, flag, info = model.solve()
        if flag <= 0 and warm:
            model.update(A=qp.A, bupper=bu, blower=bl, sense=sense)
            x, _, flag, info = model.solve()
        it = int(info.get("iterations", 0))
        if flag > 0:
            return QPResult(np.array(x, dtype=np.float64), "optimal", it, f"exitflag {flag}", info)
        self._last_key = None
        status = "infeasible" if flag == -1 else "failed"
        return QPResult(None, status, it, f"exitflag {flag}", info)


class OsqpSolver(QPSolver):
    """OSQP (ADMM, sparse; Stellato et al. 2020, the paper's solver) through its own API."""

    name = "osqp"
    defaults: ClassVar[Mapping[str, Any]] = {
        "eps_abs": 1e-7,
        "eps_rel": 1e-7,
        "polishing": True,
        "max_iter": 20000,
        "verbose": False,
    }

    def __init__(self, settings: Mapping[str, Any] | None = None) -> None:
        import osqp  # noqa: F401

        super().__init__(settings)

    def _solve(self, qp: DenseQP, x0: FloatArray | None, warm: bool) -> QPResult:
        import osqp
        import scipy.sparse as spa

        n = qp.p_diag.size
        P = spa.diags(qp.p_diag, format="csc")
        A = spa.vstack((spa.csc_matrix(qp.A), spa.eye(n, format="csc")), format="csc")
        lo = np.concatenate((qp.lower, qp.lb))
        up = np.concatenate((qp.upper, qp.ub))
        solver = osqp.OSQP()
        solver.setup(P, np.zeros(n), A, lo, up, **self.settings)
        if x0 is not None:
            solver.warm_start(x=x0)
        res = solver.solve(raise_error=False)
        st = osqp.SolverStatus
        it = int(res.info.iter)
        if res.info.status_val == st.OSQP_SOLVED:
            return QPResult(np.asarray(res.x), "optimal", it, res.info.status, res)
        if res.info.status_val in (st.OSQP_PRIMAL_INFEASIBLE, st.OSQP_PRIMAL_INFEASIBLE_INACCURATE):
            return QPResult(None, "infeasible", it, res.info.status, res)
        return QPResult(None, "failed", it, res.info.status, res)


class PiqpSolver(QPSolver):
    """PIQP (proximal interior point; Schwan et al. 2023) through its own sparse API.

    The sparse KKT solver is used: with the diagonal Hessian of the solved form it is several
    times faster than PIQP's dense one from ~45 contacts on.
    """

    name = "piqp"
    defaults: ClassVar[Mapping[str, Any]] = {"verbose": False}
    primal_warm_start = False  # interior point: no primal warm start

    def __init__(self, settings: Mapping[str, Any] | None = None) -> None:
        import piqp  # noqa: F401

        super().__init__(settings)

    def _solve(self, qp: DenseQP, x0: FloatArray | None, warm: bool) -> QPResult:
        import piqp
        import scipy.sparse as spa

        n = qp.p_diag.size
        e = qp.n_eq
        solver = piqp.SparseSolver()
        for k, v in self.settings.items():
            setattr(solver.settings, k, v)
        solver.setup(
            spa.diags(qp.p_diag, format="csc"),
            np.zeros(n),
            spa.csc_matrix(qp.A[:e]),
            qp.upper[:e].copy(),
            spa.csc_matrix(qp.A[e:]),
            qp.lower[e:].copy(),
            qp.upper[e:].copy(),
            None if np.isneginf(qp.lb).all() else qp.lb.copy(),
            None if np.isposinf(qp.ub).all() else qp.ub.copy(),
        )
        status = solver.solve()
        res = solver.result
        it = int(res.info.iter)
        if status == piqp.PIQP_SOLVED:
            return QPResult(np.asarray(res.x).copy(), "optimal", it, str(status), res)
        if status == piqp.PIQP_PRIMAL_INFEASIBLE:
            return QPResult(None, "infeasible", it, str(status), res)
        return QPResult(None, "failed", it, str(status), res)


class QpsolversSolver(QPSolver):
    """Any solver of :mod:`qpsolvers`, through :func:`qpsolvers.solve_problem`.

    Solver warnings are silenced (the outcome is in the status); a solver that is not found
    reports ``"failed"``, since qpsolvers does not say whether the problem was infeasible. Some
    qpsolvers adapters (e.g. PIQP's) silently ignore unknown settings.
    """

    name = "qpsolvers"
    solver_defaults: ClassVar[Mapping[str, Mapping[str, Any]]] = {
        "osqp": {
            "eps_abs": 1e-7,
            "eps_rel": 1e-7,
            "polishing": True,
            "max_iter": 20000,
            "raise_error": False,
        },
        "daqp": {"primal_tol": 1e-9},
        "piqp": {"eps_abs": 1e-8, "eps_rel": 1e-9},
        "clarabel": {"tol_feas": 1e-9, "tol_gap_abs": 1e-9, "tol_gap_rel": 1e-9},
        "proxqp": {"eps_abs": 1e-9, "eps_rel": 0.0},
    }
    """Tight settings per qpsolvers backend, under the user's ``settings``."""

    def __init__(self, solver: str, settings: Mapping[str, Any] | None = None) -> None:
        super().__init__({**self.solver_defaults.get(solver, {}), **(settings or {})})
        self.solver = solver

    def _solve(self, qp: DenseQP, x0: FloatArray | None, warm: bool) -> QPResult:
        import qpsolvers
        import scipy.sparse as spa

        e = qp.n_eq
        rows, h = [], []
        for sign, lim in ((1.0, qp.upper[e:]), (-1.0, -qp.lower[e:])):
            keep = np.isfinite(lim)
            rows.append(sign * qp.A[e:][keep])
            h.append(lim[keep])
        G = np.vstack(rows)
        sparse = self.solver in qpsolvers.sparse_solvers and self.solver not in (
            qpsolvers.dense_solvers
        )
        P: Any = np.diag(qp.p_diag)
        Aeq: Any = qp.A[:e]
        if sparse:
            P, G, Aeq = spa.diags(qp.p_diag, format="csc"), spa.csc_matrix(G), spa.csc_matrix(Aeq)
        problem = qpsolvers.Problem(
            P, np.zeros(qp.p_diag.size), G, np.concatenate(h), Aeq, qp.upper[:e], qp.lb, qp.ub
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sol = qpsolvers.solve_problem(problem, solver=self.solver, initvals=x0, **self.settings)
        if sol.found and sol.x is not None:
            return QPResult(np.asarray(sol.x), "optimal", 0, "found", sol)
        return QPResult(None, "failed", 0, "not found", sol)


NATIVE_SOLVERS: dict[str, type[QPSolver]] = {}
"""Solvers driven through their own API, filled by guarded imports."""

for _cls, _module in ((DaqpSolver, "daqp"), (OsqpSolver, "osqp"), (PiqpSolver, "piqp")):
    try:
        __import__(_module)
    except ImportError:  # pragma: no cover - depends on the environment
        continue
    NATIVE_SOLVERS[_cls.name] = _cls

DEFAULT_SOLVER: str = "daqp"
"""Fastest exact solver on the benchmark (``wholehand bench allocate``)."""


def _qpsolvers_available() -> list[str]:
    try:
        import qpsolvers
    except ImportError:  # pragma: no cover
        return []
    return list(qpsolvers.available_solvers)


def available_solvers() -> list[str]:
    """Every solver name :func:`make_solver` accepts in this environment."""
    generic = _qpsolvers_available()
    plain = [s for s in generic if s not in NATIVE_SOLVERS]
    return [*NATIVE_SOLVERS, *plain, *(f"qpsolvers:{s}" for s in generic)]


def make_solver(
    name: str, settings: Mapping[str, Any] | None = None, owner: str = "make_solver"
) -> QPSolver:
    """The adapter for solver ``name`` with ``settings`` on top of its defaults.

    User ``settings`` are tried once on a tiny problem, so that a bad one fails here.

    Raises:
        ConfigError: ``name`` is not an installed solver (the message lists the installed
            ones), or the solver rejects ``settings``.
    """
    generic = _qpsolvers_available()
    solver: QPSolver | None = None
    if isinstance(name, str):
        base = name.removeprefix("qpsolvers:")
        if name in NATIVE_SOLVERS:
            solver = NATIVE_SOLVERS[name](settings)
        elif base in generic:
            solver = QpsolversSolver(base, settings)
    if solver is not None:
        if settings:
            solver.probe(owner)
        return solver
    raise ConfigError(
        f"{owner}: parameter solver={name!r} is not an installed QP solver; installed: "
        f"{', '.join(available_solvers()) or 'none'}. Install another with e.g. "
        f"`pip install qpsolvers[clarabel]` or `pip install proxsuite`."
    )


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
        deadline_ns: ``time.perf_counter_ns()`` past which no further solve starts: a solution
            that still violates a left-out row then ends with status ``"deadline"`` and no x.
            None: no deadline.
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
        rounds += 1
        full = rounds > max_rounds
        if full:
            t_in, n_in = all_t, all_n
        res = solver.solve(
            dense_qp(qp, t_in, n_in),
            x0 if solver.primal_warm_start else None,
            warm=warm or x0 is not None,
        )
        iterations += res.iterations
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
        if deadline_ns is not None and time.perf_counter_ns() > deadline_ns:
            return AllocationSolution(
                x=None,
                status="deadline",
                rounds=rounds,
                n_rows=t_in.size + n_in.size,
                iterations=iterations,
                violation=np.inf,
                detail="deadline passed with rows still violated",
                torque_sel=t_in,
                null_sel=n_in,
            )
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
    "DEFAULT_SOLVER",
    "FEAS_TOL",
    "AllocationSolution",
    "DenseQP",
    "QPSolver",
    "QPResult",
    "WarmStart",
    "available_solvers",
    "binding_rows",
    "dense_qp",
    "make_solver",
    "solve_allocation",
]
