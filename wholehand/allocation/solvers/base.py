"""The dense QP every solver adapter takes, its result, and the adapter interface.

``min 1/2 x^T diag(p) x`` subject to ``lower <= A x <= upper`` (the first ``n_eq`` rows
equalities) and ``lb <= x <= ub``: the allocation QP of one screening round
(:func:`wholehand.allocation.solve.dense_qp`).
"""

from __future__ import annotations

import abc
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from wholehand.errors import ConfigError

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

BIG: float = 1e30
"""Stand-in for infinite bounds in solvers that want finite numbers."""


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
    active: IntArray | None = None
    """(n + m,) guessed active set, variable bounds first, then rows: -1 at the lower bound, +1
    at the upper one, 0 inactive (equality rows are active anyway); None: no guess. Solvers
    that :attr:`~QPSolver.reports_duals` start from it."""


@dataclass
class QPResult:
    """What an adapter returns."""

    x: FloatArray | None
    """(n,) primal solution, None when none was found."""
    status: str
    """``"optimal"``, ``"infeasible"``, ``"failed"`` or ``"deadline"`` (stopped at its time
    limit)."""
    iterations: int = 0
    """Solver iterations."""
    detail: str = ""
    """Solver-specific status text."""
    raw: Any = None
    """The solver's own result object, for debugging."""
    duals: FloatArray | None = None
    """(n + m,) multipliers at the solution, from solvers that :attr:`~QPSolver.reports_duals`:
    ``z`` of the variable bounds, then ``y`` of the rows, with ``diag(p) x + A^T y + z = 0``;
    > 0 at an upper bound, < 0 at a lower one, 0 where inactive."""


class QPSolver(abc.ABC):
    """Adapter from :class:`DenseQP` to one solver."""

    name: ClassVar[str] = ""
    """Registry name."""
    defaults: ClassVar[Mapping[str, Any]] = {}
    """Settings used unless overridden: tight enough for exact-looking allocations."""
    primal_warm_start: ClassVar[bool] = True
    """Whether the solver uses the values of a primal start ``x0``."""
    reports_duals: ClassVar[bool] = False
    """Whether results carry exact :attr:`QPResult.duals` and solves start from
    :attr:`DenseQP.active` (the allocation then screens the edge weights too)."""
    time_limited: ClassVar[bool] = False
    """Whether the solver itself stops at ``time_limit`` (others only finish the solve)."""

    def __init__(self, settings: Mapping[str, Any] | None = None) -> None:
        self.settings: dict[str, Any] = {**self.defaults, **(settings or {})}

    def solve(
        self,
        qp: DenseQP,
        x0: FloatArray | None = None,
        warm: bool = False,
        time_limit: float | None = None,
    ) -> QPResult:
        """Solve ``qp``; never raises (a solver exception becomes status ``"failed"``).

        Args:
            qp: The problem.
            x0: (n,) primal start, used by solvers with :attr:`primal_warm_start`.
            warm: ``qp`` continues the previous solve (next control cycle, or the next screening
                round): solvers that keep state (DAQP's working set) may start from it.
            time_limit: Wall time the solve may take [s], > 0; None: no limit. Solvers with
                :attr:`time_limited` stop near it with status ``"deadline"`` (they check the
                clock every few iterations); the others ignore it.
        """
        try:
            return self._solve(qp, x0, warm, time_limit)
        except Exception as err:  # the control loop must not raise on a solver error
            self.reset()
            return QPResult(None, "failed", 0, f"{type(err).__name__}: {err}", err)

    @abc.abstractmethod
    def _solve(
        self, qp: DenseQP, x0: FloatArray | None, warm: bool, time_limit: float | None
    ) -> QPResult:
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
            self._solve(qp, None, False, None)
        except Exception as err:
            raise ConfigError(
                f"{owner}: solver {self.name!r} rejected solver_settings={self.settings!r}: "
                f"{type(err).__name__}: {err}"
            ) from err
        finally:
            self.reset()
