"""The allocation QP's rows for the dual active-set solver
(:mod:`wholehand.allocation.solvers.dual_active_set_kernel`): the dense ones, and the
consistency rows ``N_u^T W_act`` held implicitly through the Householder QR of the actuation
Jacobian (``N_u`` the last columns of its ``Q``), formed one at a time when needed.
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

from wholehand.jit import CACHE

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


@numba.njit(cache=CACHE, nogil=True)
def implicit_values(
    qr: FloatArray,
    tau: FloatArray,
    W: FloatArray,
    act_idx: IntArray,
    x: FloatArray,
    f: FloatArray,
    out: FloatArray,
) -> None:
    """``out[:mq - kq] = N_u^T f_act(x)``: every consistency value, ``N_u`` the columns of the
    Householder ``Q`` (``qr``, ``tau`` as LAPACK's ``dgeqrf`` leaves them) past the first ``kq``;
    ``f`` (mq,) is scratch."""
    mq, kq = qr.shape
    for a in range(act_idx.size):
        i = act_idx[a]
        for d in range(3):
            s = 0.0
            for e in range(4):
                s += W[i, d, e] * x[4 * i + e]
            f[3 * a + d] = s
    for i in range(kq):  # Q^T f = H_k ... H_1 f
        s = f[i]
        for q in range(i + 1, mq):
            s += qr[q, i] * f[q]
        s *= tau[i]
        f[i] -= s
        for q in range(i + 1, mq):
            f[q] -= s * qr[q, i]
    for r in range(mq - kq):
        out[r] = f[kq + r]


@numba.njit(cache=CACHE, nogil=True)
def implicitrow(
    qr: FloatArray,
    tau: FloatArray,
    W: FloatArray,
    act_idx: IntArray,
    r: int,
    scale: float,
    u: FloatArray,
    out: FloatArray,
) -> None:
    """``out = scale * (N_u^T W_act)[r]``: consistency row ``r`` on the edge weights, from
    ``N_u[:, r] = Q e_(kq + r)``; ``u`` (mq,) is scratch."""
    mq, kq = qr.shape
    for q in range(mq):
        u[q] = 0.0
    u[kq + r] = 1.0
    for i in range(kq - 1, -1, -1):  # Q u = H_1 ... H_k u
        s = u[i]
        for q in range(i + 1, mq):
            s += qr[q, i] * u[q]
        s *= tau[i]
        u[i] -= s
        for q in range(i + 1, mq):
            u[q] -= s * qr[q, i]
    for j in range(out.size):
        out[j] = 0.0
    for a in range(act_idx.size):
        i = act_idx[a]
        for e in range(4):
            s = 0.0
            for d in range(3):
                s += u[3 * a + d] * W[i, d, e]
            out[4 * i + e] = scale * s


@numba.njit(cache=CACHE, nogil=True)
def row(
    A: FloatArray,
    qr: FloatArray,
    tau: FloatArray,
    W: FloatArray,
    act_idx: IntArray,
    r: int,
    scale: float,
    u: FloatArray,
    out: FloatArray,
) -> None:
    """``out = scale * row r`` of the problem: a dense row of ``A`` or a consistency row."""
    md = A.shape[0]
    if r < md:
        for j in range(out.size):
            out[j] = scale * A[r, j]
    else:
        implicitrow(qr, tau, W, act_idx, r - md, scale, u, out)
