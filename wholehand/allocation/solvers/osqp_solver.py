"""OSQP through its own API (ADMM, sparse; the paper's solver)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from wholehand.allocation.solvers.base import DenseQP, FloatArray, QPResult, QPSolver


class OsqpSolver(QPSolver):
    """OSQP (ADMM, sparse; Stellato et al. 2020, the paper's solver) through its own API."""

    name = "osqp"
    time_limited = True
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

    def _solve(
        self, qp: DenseQP, x0: FloatArray | None, warm: bool, time_limit: float | None
    ) -> QPResult:
        import osqp
        import scipy.sparse as spa

        n = qp.p_diag.size
        P = spa.diags(qp.p_diag, format="csc")
        A = spa.vstack((spa.csc_matrix(qp.A), spa.eye(n, format="csc")), format="csc")
        lo = np.concatenate((qp.lower, qp.lb))
        up = np.concatenate((qp.upper, qp.ub))
        solver = osqp.OSQP()
        settings = dict(self.settings)
        if time_limit is not None:
            settings["time_limit"] = time_limit
        solver.setup(P, np.zeros(n), A, lo, up, **settings)
        if x0 is not None:
            solver.warm_start(x=x0)
        res = solver.solve(raise_error=False)
        st = osqp.SolverStatus
        it = int(res.info.iter)
        if res.info.status_val == st.OSQP_SOLVED:
            return QPResult(np.asarray(res.x), "optimal", it, res.info.status, res)
        if res.info.status_val == st.OSQP_TIME_LIMIT_REACHED:
            return QPResult(None, "deadline", it, res.info.status, res)
        if res.info.status_val in (st.OSQP_PRIMAL_INFEASIBLE, st.OSQP_PRIMAL_INFEASIBLE_INACCURATE):
            return QPResult(None, "infeasible", it, res.info.status, res)
        return QPResult(None, "failed", it, res.info.status, res)
