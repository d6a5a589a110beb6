"""Numba kernels of the allocation's screening loop (:mod:`wholehand.allocation.solve`): a
round's rows and bounds (its edge weights' columns only), the left-out rows a solution violates,
the rows at their bounds, the row selections, the pricing of the left-out edge weights and the
active sets by identity that carry one round's solution into the next.

Each replaced a handful of numpy calls of a few microseconds each; near a loss, with several
screening rounds per cycle, that Python took more time than DAQP (docs/results.md). How they
round: docs/performance.md, "How the kernels round".

Compilation as for the contact kernels (``wholehand_plugins.mesh_sdf.kernels``): ``cache=CACHE``,
``error_model="numpy"``.
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

from wholehand.jit import CACHE

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def solved_rows(
    G_lam: FloatArray,
    T_lam: FloatArray,
    torque_sel: IntArray,
    null_rows: FloatArray,
    w_ext: FloatArray,
    f_n_min: float,
    t_lower: FloatArray,
    t_upper: FloatArray,
    eps: float,
    edge_sel: IntArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:  # pragma: no cover - jit
    """The rows of the solved form over ``x = [lambda[edge_sel] (k); w (6)]`` and their bounds
    (the other edge weights held at zero): the wrench equality ``G_lam lambda - w = -w_ext``,
    the minimum squeeze ``sum(lambda) >= f_n_min``, the torque rows ``T_lam[torque_sel]``
    within ``[t_lower, t_upper][torque_sel]`` (bounds of every torque row, (n_t,)) and the
    consistency rows ``null_rows`` (nn, nl) within ``+-eps``.

    Returns:
        ``A`` (7 + nt + nn, k + 6), ``lower`` and ``upper`` (7 + nt + nn,).
    """
    k = edge_sel.size
    nt, nn = torque_sel.size, null_rows.shape[0]
    m = 7 + nt + nn
    A = np.zeros((m, k + 6))
    lower = np.empty(m)
    upper = np.empty(m)
    for r in range(6):
        for c in range(k):
            A[r, c] = G_lam[r, edge_sel[c]]
        A[r, k + r] = -1.0
        lower[r] = upper[r] = -w_ext[r]
    A[6, :k] = 1.0
    lower[6], upper[6] = f_n_min, np.inf
    for t in range(nt):
        row = torque_sel[t]
        for c in range(k):
            A[7 + t, c] = T_lam[row, edge_sel[c]]
        lower[7 + t], upper[7 + t] = t_lower[row], t_upper[row]
    for j in range(nn):
        for c in range(k):
            A[7 + nt + j, c] = null_rows[j, edge_sel[c]]
        lower[7 + nt + j], upper[7 + nt + j] = -eps, eps
    return A, lower, upper


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def priced_edges(
    G_lam: FloatArray,
    T_lam: FloatArray,
    torque_sel: IntArray,
    null_rows: FloatArray,
    y: FloatArray,
    in_problem: BoolArray,
    tol: float,
) -> IntArray:  # pragma: no cover - jit
    """The edge weights left out of a screening round (``in_problem`` False) whose bound
    ``lambda_j >= 0`` would need a multiplier below ``-tol``: ``A_j . y < -tol``, with ``A_j``
    the edge's column in the round's rows (as :func:`solved_rows` stacks them: wrench, squeeze,
    ``T_lam[torque_sel]``, ``null_rows``) and ``y`` (m,) their multipliers. Increasing."""
    nl = G_lam.shape[1]
    nt, nn = torque_sel.size, null_rows.shape[0]
    out = np.empty(nl, dtype=np.intp)
    n_out = 0
    for j in range(nl):
        if in_problem[j]:
            continue
        price = y[6]  # the squeeze row's coefficient is 1
        for r in range(6):
            price += G_lam[r, j] * y[r]
        for t in range(nt):
            price += T_lam[torque_sel[t], j] * y[7 + t]
        for q in range(nn):
            price += null_rows[q, j] * y[7 + nt + q]
        if price < -tol:
            out[n_out] = j
            n_out += 1
    return out[:n_out]


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def rows_over(
    values: FloatArray, limits: FloatArray, included: BoolArray, tol: float
) -> tuple[IntArray, float]:
    """Two-sided rows ``|values| <= limits`` at a relaxed solution: the left-out ones
    (``included`` False) violated by more than ``tol``, increasing, and the largest
    ``|values| - limits`` over all rows (0 for none) [N or N*m]."""
    add = np.empty(values.size, dtype=np.intp)
    n_add = 0
    worst = 0.0
    for i in range(values.size):
        over = abs(values[i]) - limits[i]
        if over > worst or np.isnan(over):
            worst = over
        if over > tol and not included[i]:
            add[n_add] = i
            n_add += 1
    return add[:n_add], worst


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def at_bounds(values: FloatArray, limits: FloatArray, rel: float, abs_tol: float) -> IntArray:
    """Indices of the two-sided rows ``|values| <= limits`` at or past their bounds:
    ``|values| >= limits (1 - rel) - abs_tol``, increasing."""
    out = np.empty(values.size, dtype=np.intp)
    n = 0
    for i in range(values.size):
        if abs(values[i]) >= limits[i] * (1.0 - rel) - abs_tol:
            out[n] = i
            n += 1
    return out[:n]


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def active_of(
    duals: FloatArray,
    n_lambda: int,
    edge_sel: IntArray,
    torque_sel: IntArray,
    null_sel: IntArray,
    n_t: int,
    n_null: int,
) -> tuple[IntArray, int, IntArray, IntArray]:  # pragma: no cover - jit
    """The active set of a screening round's solution by identity (-1 at the lower bound, +1 at
    the upper one, 0 inactive), from the solver's (n + m,) multipliers of the problem with the
    edge weights ``edge_sel``, the torque rows ``torque_sel`` and the consistency rows
    ``null_sel`` (:class:`~wholehand.allocation.solution.ActiveSet`): every edge bound (-1 for
    those left out, held at zero), the squeeze, every torque row, every consistency row."""
    n_edges = edge_sel.size
    edges = np.full(n_lambda, -1, dtype=np.intp)
    for c in range(n_edges):
        edges[edge_sel[c]] = _sign(duals[c])
    rows = n_edges + 6  # after the free wrench variables' bounds; then the 6 equality rows
    torque = np.zeros(n_t, dtype=np.intp)
    for t in range(torque_sel.size):
        torque[torque_sel[t]] = _sign(duals[rows + 7 + t])
    null = np.zeros(n_null, dtype=np.intp)
    for q in range(null_sel.size):
        null[null_sel[q]] = _sign(duals[rows + 7 + torque_sel.size + q])
    return edges, _sign(duals[rows + 6]), torque, null


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _sign(v: float) -> int:  # pragma: no cover - jit
    return 1 if v > 0.0 else (-1 if v < 0.0 else 0)


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def active_vector(
    edges: IntArray,
    squeeze: int,
    torque: IntArray,
    null: IntArray,
    edge_sel: IntArray,
    torque_sel: IntArray,
    null_sel: IntArray,
) -> IntArray:  # pragma: no cover - jit
    """The (n + m,) guessed active set of the problem with these edge weights and rows, from
    one by identity (:func:`active_of`): the edge bounds, the free wrench variables' (0), the
    equality rows (0), the squeeze, the torque rows, the consistency rows."""
    k, nt, nn = edge_sel.size, torque_sel.size, null_sel.size
    out = np.zeros(k + 13 + nt + nn, dtype=np.intp)
    for c in range(k):
        out[c] = edges[edge_sel[c]]
    out[k + 12] = squeeze
    for t in range(nt):
        out[k + 13 + t] = torque[torque_sel[t]]
    for q in range(nn):
        out[k + 13 + nt + q] = null[null_sel[q]]
    return out


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def selection(sel: IntArray, size: int) -> tuple[BoolArray, IntArray]:
    """The (size,) mask of the indices ``sel`` below ``size``, and those indices sorted without
    repeats."""
    mask = np.zeros(size, dtype=np.bool_)
    for i in sel:
        if i < size:
            mask[i] = True
    return mask, np.flatnonzero(mask)


__all__ = [
    "active_of",
    "active_vector",
    "at_bounds",
    "priced_edges",
    "rows_over",
    "selection",
    "solved_rows",
]
