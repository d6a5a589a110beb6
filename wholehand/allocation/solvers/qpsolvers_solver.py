"""Any solver of qpsolvers, through ``qpsolvers.solve_problem``."""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from wholehand.allocation.solvers.base import DenseQP, FloatArray, QPResult, QPSolver


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

    def _solve(
        self, qp: DenseQP, x0: FloatArray | None, warm: bool, time_limit: float | None
    ) -> QPResult:
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
