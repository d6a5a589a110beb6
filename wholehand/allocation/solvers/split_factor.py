"""The Cholesky factor of the dual active-set solver's split form and its updates
(:mod:`wholehand.allocation.solvers.dual_active_set_kernel`).

``T = C D^-1 C^T`` with ``C = [[G_F, -I], [A_RF, 0]]`` over the free weights ``F`` and the
active rows ``R`` (their coefficients signed, ``Aact``), ``D = diag(reg I, I)``: (6 + k) x
(6 + k). A weight freed or fixed is a rank-one update or downdate, a row leaving removes a row
and a column; each O((6 + k)^2).
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

from wholehand.jit import CACHE

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


@numba.njit(cache=CACHE, nogil=True)
def rank_one(L: FloatArray, start: int, dim: int, v: FloatArray, sigma: float) -> bool:
    """``L L^T += sigma v v^T`` on the trailing block ``[start:dim, start:dim]`` (``v`` indexed
    the same way; overwritten); False if a downdate loses positive definiteness."""
    for k in range(start, dim):
        lkk = L[k, k]
        r2 = lkk * lkk + sigma * v[k] * v[k]
        if not r2 > 1e-300:
            return False
        r = np.sqrt(r2)
        c = r / lkk
        s = v[k] / lkk
        L[k, k] = r
        for i in range(k + 1, dim):
            L[i, k] = (L[i, k] + sigma * s * v[i]) / c
            v[i] = c * v[i] - s * L[i, k]
    return True


@numba.njit(cache=CACHE, nogil=True)
def forward(L: FloatArray, dim: int, b: FloatArray) -> None:
    """``b = L^-1 b`` in place (leading ``dim``)."""
    for i in range(dim):
        v = b[i]
        for k in range(i):
            v -= L[i, k] * b[k]
        b[i] = v / L[i, i]


@numba.njit(cache=CACHE, nogil=True)
def backward(L: FloatArray, dim: int, b: FloatArray) -> None:
    """``b = L^-T b`` in place (leading ``dim``)."""
    for i in range(dim - 1, -1, -1):
        v = b[i]
        for k in range(i + 1, dim):
            v -= L[k, i] * b[k]
        b[i] = v / L[i, i]


@numba.njit(cache=CACHE, nogil=True)
def factor(
    L: FloatArray, G: FloatArray, Aact: FloatArray, k: int, F: IntArray, nf: int, reg: float
) -> bool:
    """Build ``T`` (module docstring) for the free weights ``F[:nf]`` and the active rows'
    signed coefficients ``Aact[:k]`` in ``L`` and factor it in place; False if it is not
    positive definite."""
    dim = 6 + k
    for a in range(dim):
        for b in range(a + 1):
            s = 0.0
            for i in range(nf):
                j = F[i]
                ca = G[a, j] if a < 6 else Aact[a - 6, j]
                cb = G[b, j] if b < 6 else Aact[b - 6, j]
                s += ca * cb
            s /= reg
            if a == b and a < 6:
                s += 1.0
            L[a, b] = s
    for j in range(dim):
        d = L[j, j]
        for i in range(j):
            d -= L[j, i] * L[j, i]
        if not d > 0.0:
            return False
        d = np.sqrt(d)
        L[j, j] = d
        for i in range(j + 1, dim):
            v = L[i, j]
            for q in range(j):
                v -= L[i, q] * L[j, q]
            L[i, j] = v / d
    return True


@numba.njit(cache=CACHE, nogil=True)
def column(G: FloatArray, Aact: FloatArray, k: int, j: int, scale: float, out: FloatArray) -> None:
    """``out[:6 + k] = scale * [g_j; a_Rj]``: weight ``j``'s column of ``C``."""
    for a in range(6):
        out[a] = scale * G[a, j]
    for q in range(k):
        out[6 + q] = scale * Aact[q, j]


@numba.njit(cache=CACHE, nogil=True)
def drop_row(L: FloatArray, dim: int, p: int, work: FloatArray) -> bool:
    """Remove row and column ``p`` of ``T`` from its factor (``dim`` -> ``dim - 1``)."""
    for i in range(p + 1, dim):
        work[i - 1] = L[i, p]
    for i in range(p + 1, dim):
        for q in range(p):
            L[i - 1, q] = L[i, q]
        for q in range(p + 1, i + 1):
            L[i - 1, q - 1] = L[i, q]
    return rank_one(L, p, dim - 1, work, 1.0)
