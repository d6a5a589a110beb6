"""The outcome of the allocation's solve (:func:`~wholehand.allocation.solve.solve_allocation`)
and the active set one screening round hands to the next."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import cast

import numpy as np
import numpy.typing as npt

from wholehand.allocation.problem import AllocationQP
from wholehand.allocation.screening_kernels import active_of, active_vector

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


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
    relative_violation: float = np.inf
    """:attr:`violation` relative to each constraint's scale [-] (inf if none): a torque row's
    excess as a fraction of its joint's limit, the edge weights' (``lambda >= 0``), the minimum
    squeeze's and the consistency rows' as a fraction of the allocation's force scale
    ``max(f_n_min, sum(lambda))``. Absolute tolerances would let a tiny torque limit be
    exceeded many times over, and reject accurate answers to a large squeeze."""
    detail: str = ""
    """Solver status text of the last solve."""
    solver_time: float = 0.0
    """Wall time inside the solver's calls, all rounds [s]."""
    torque_sel: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    """Positions in ``qp.torque_rows`` of the torque rows in the last solve."""
    null_sel: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    """Consistency rows in the last solve."""
    torque_values: FloatArray = field(default_factory=lambda: np.zeros(0))
    """(n_t,) torques of every torque row at ``x`` [N*m] (``qp.T_lam @ lambda``); status
    ``"deadline"``: at :attr:`x_relaxed` (empty without it)."""
    null_values: FloatArray = field(default_factory=lambda: np.zeros(0))
    """(n_null,) every consistency value ``N_u^T f_act`` at ``x`` [N]; status ``"deadline"``:
    at :attr:`x_relaxed` (empty without it)."""
    n_edges: int = 0
    """Edge weights that were variables of the last solve (the others held at zero)."""
    x_relaxed: FloatArray | None = None
    """Status ``"deadline"``: the solution of the last finished round, optimal with fewer rows
    but violating some others (no command; a warm start for the next cycle), or None."""


@dataclass
class ActiveSet:
    """Which constraints of the allocation QP held at a solution, by identity (-1 at the lower
    bound, +1 at the upper one, 0 inactive), so that a larger problem of the next screening
    round can start from them."""

    edges: IntArray
    """(4N,) the bounds ``lambda_j >= 0``. Edge weights left out of the problem were held at
    zero, so they count as at their bound: a round that adds them starts from the last round's
    solution instead of rebuilding their bounds one solver iteration each (the fallback to the
    full problem took as many iterations as a cold solve before)."""
    squeeze: int
    """The minimum squeeze."""
    torque: IntArray
    """(n_t,) the torque rows (positions in ``qp.torque_rows``)."""
    null: IntArray
    """(n_null,) the consistency rows."""

    @classmethod
    def of(
        cls,
        qp: AllocationQP,
        duals: FloatArray,
        torque_sel: IntArray,
        null_sel: IntArray,
        edge_sel: IntArray | None,
    ) -> ActiveSet:
        """From a solver's (n + m,) multipliers of the problem with these rows and edges."""
        edges = np.arange(qp.n_lambda, dtype=np.intp) if edge_sel is None else edge_sel
        n_t, n_null = qp.torque_rows.size, qp.n_null
        state = active_of(duals, qp.n_lambda, edges, torque_sel, null_sel, n_t, n_null)
        return cls(state[0], int(state[1]), state[2], state[3])

    def vector(
        self, torque_sel: IntArray, null_sel: IntArray, edge_sel: IntArray | None
    ) -> IntArray:
        """The (n + m,) :attr:`DenseQP.active` of the problem with these rows and edges."""
        edges = np.arange(self.edges.size, dtype=np.intp) if edge_sel is None else edge_sel
        vector = active_vector(
            self.edges, self.squeeze, self.torque, self.null, edges, torque_sel, null_sel
        )
        return cast(IntArray, vector)
