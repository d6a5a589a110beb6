"""DAQP through its own API (dense dual active set; the dual active-set solver's fallback)."""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numba
import numpy as np
import numpy.typing as npt

from wholehand.allocation.solvers.base import (
    BIG,
    DenseQP,
    FloatArray,
    IntArray,
    QPResult,
    QPSolver,
)
from wholehand.errors import ConfigError
from wholehand.jit import CACHE

SenseArray = npt.NDArray[np.intc]

_EXIT_TIMELIMIT = -7
"""DAQP's exit flag for a solve stopped at its time limit."""
# DAQP's constraint flags (its include/constants.h).
_ACTIVE = 1
_LOWER = 2
_IMMUTABLE = 4


class DaqpSolver(QPSolver):
    """DAQP (dual active set, dense; Arnström et al. 2022) through its own API.

    One ``daqp.Model`` is kept per problem shape ``(n, m)``, so the Hessian is processed once
    and each cycle only updates ``A`` and the bounds. A warm solve (``warm``, same shape as the
    previous solve) starts from the previous solve's working set, any other from the guessed
    active set :attr:`DenseQP.active` when there is one; if a warm solve fails, the problem is
    solved again from an empty working set. The values of ``x0`` are not used.
    """

    name = "daqp"
    time_limited = True
    reports_duals = True
    defaults: ClassVar[Mapping[str, Any]] = {"primal_tol": 1e-9, "iter_limit": 2000}
    primal_warm_start = False
    max_models: ClassVar[int] = 8
    """Problem shapes kept (least recently used dropped first)."""

    def __init__(self, settings: Mapping[str, Any] | None = None) -> None:
        import daqp  # fail at construction when missing

        super().__init__(settings)
        known = daqp.Model().settings
        unknown = set(self.settings) - set(known)
        if unknown:
            raise ConfigError(
                f"DAQP: solver_settings holds unknown names {sorted(unknown)}; known: "
                f"{sorted(known)}"
            )
        self._time_limit = float(self.settings.get("time_limit", known["time_limit"]))
        """A new model's time limit [s] (0: none)."""
        self._models: OrderedDict[tuple[int, int, int], _Kept] = OrderedDict()
        self._last_key: tuple[int, int, int] | None = None

    def reset(self) -> None:
        """Drop the kept models (and with them the warm-start state)."""
        self._models.clear()
        self._last_key = None

    def _solve(
        self, qp: DenseQP, x0: FloatArray | None, warm: bool, time_limit: float | None
    ) -> QPResult:
        import daqp

        n = qp.p_diag.size
        key = (n, qp.A.shape[0], qp.n_eq)
        bu, bl = _bounds(qp.ub, qp.upper, qp.lb, qp.lower, BIG)
        kept = self._models.get(key)
        sense = _equality_sense(n, bu.size, qp.n_eq) if kept is None else kept.sense
        own = warm and key == self._last_key and kept is not None
        start = sense
        if qp.active is not None and not own:
            start = _start_flags(sense, qp.active, n, qp.n_eq)
        warm = own or start is not sense
        if kept is None or not (kept.p_diag is qp.p_diag or np.array_equal(kept.p_diag, qp.p_diag)):
            model = daqp.Model()
            model.settings = self.settings  # known names (checked at construction)
            model.setup(np.diag(qp.p_diag), np.zeros(n), qp.A, bu, bl, start)
            # An immutable diagonal is kept as it is, so that the next solve of this shape (the
            # allocation passes one array per size) is recognised by identity.
            fixed = not qp.p_diag.flags.writeable and qp.p_diag.flags.owndata
            p_diag = qp.p_diag if fixed else qp.p_diag.copy()
            kept = _Kept(model, p_diag, sense, self._time_limit)
            self._models[key] = kept
            warm = start is not sense
        else:
            model = kept.model
            self._models.move_to_end(key)
            if own:
                model.update(A=qp.A, bupper=bu, blower=bl)
            else:
                model.update(A=qp.A, bupper=bu, blower=bl, sense=start)
        while len(self._models) > self.max_models:
            self._models.popitem(last=False)
        self._last_key = key
        started = time.perf_counter()
        kept.set_time_limit(time_limit)
        x, _, flag, info = model.solve()
        if flag <= 0 and flag != _EXIT_TIMELIMIT and warm:
            model.update(A=qp.A, bupper=bu, blower=bl, sense=sense)
            if time_limit is not None:
                kept.set_time_limit(time_limit - (time.perf_counter() - started))
            x, _, flag, info = model.solve()
        it = int(info.get("iterations", 0))
        if flag > 0:  # DAQP returns copies of its buffers
            x = np.asarray(x, dtype=np.float64)
            duals = np.asarray(info["lam"], dtype=np.float64)
            return QPResult(x, "optimal", it, f"exitflag {flag}", info, duals)
        self._last_key = None
        status = {-1: "infeasible", _EXIT_TIMELIMIT: "deadline"}.get(flag, "failed")
        return QPResult(None, status, it, f"exitflag {flag}", info)


@numba.njit(cache=CACHE, nogil=True)
def _bounds(
    ub: FloatArray, upper: FloatArray, lb: FloatArray, lower: FloatArray, big: float
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - jit
    """DAQP's upper and lower bounds: the variables' then the rows', infinite ones as +-big
    (NaN stays NaN, as with ``np.minimum``)."""
    n, m = ub.size, upper.size
    bu = np.empty(n + m)
    bl = np.empty(n + m)
    for i in range(n + m):
        u = ub[i] if i < n else upper[i - n]
        low = lb[i] if i < n else lower[i - n]
        bu[i] = big if u > big else u
        bl[i] = -big if low < -big else low
    return bu, bl


@numba.njit(cache=CACHE, nogil=True)
def _start_flags(
    sense: SenseArray, active: IntArray, n: int, n_eq: int
) -> SenseArray:  # pragma: no cover - jit
    """DAQP's constraint flags that start a solve from the guessed active set ``active``
    (:attr:`DenseQP.active`), the equality rows active whatever the guess."""
    start: SenseArray = sense.copy()
    for i in range(active.size):
        if active[i] > 0:
            start[i] = _ACTIVE
        elif active[i] < 0:
            start[i] = _ACTIVE | _LOWER
    for i in range(n, n + n_eq):
        start[i] = _ACTIVE | _IMMUTABLE
    return start


def _equality_sense(n: int, size: int, n_eq: int) -> SenseArray:
    """DAQP's constraint flags of a problem with ``n`` variables, ``size`` bounds in all and
    ``n_eq`` leading equality rows, nothing else active (kept with the model and never written
    to: DAQP's typed buffers refuse read-only arrays)."""
    sense = np.zeros(size, dtype=np.intc)
    sense[n : n + n_eq] = _ACTIVE | _IMMUTABLE
    return sense


@dataclass
class _Kept:
    """A DAQP model of one problem shape, with what it was set up with."""

    model: Any
    p_diag: FloatArray
    """Hessian diagonal the model was set up with (the caller's array when it is immutable,
    else a copy)."""
    sense: SenseArray
    """Constraint flags with only the equality rows active."""
    time_limit: float
    """The model's time limit setting [s] (0: none), mirrored to skip DAQP's settings dict."""

    def set_time_limit(self, seconds: float | None) -> None:
        """DAQP's own time limit (0: none); a spent budget keeps a token limit, never 'none'."""
        limit = 0.0 if seconds is None else max(seconds, 1e-9)
        if self.time_limit != limit:
            self.model.settings = {"time_limit": limit}
            self.time_limit = limit
