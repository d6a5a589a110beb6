"""The compiled dual active-set method of :mod:`wholehand.allocation.solvers.dual_active_set`.

Problem, in the edge weights ``x`` (n,)::

    min  1/2 ||G x + w||^2 + reg/2 ||x||^2       G (6, n), w (6,), reg > 0
    s.t. x >= 0,   lo <= A x <= hi                A (m, n), lo <= hi, +-inf allowed

Goldfarb and Idnani's dual method (Math. Programming 27, 1983) keeps the multipliers feasible
and adds violated constraints one at a time, from the unconstrained minimiser. Two things make it
fit this problem:

- The bounds ``x_j >= 0`` it holds active are eliminated: those weights are fixed at zero and
  the algebra runs over the *free* weights ``F`` (the few that carry force). The solve starts
  with every weight fixed except a warm start's (last cycle's support), and frees weights as the
  violated constraints pull on them.
- The objective is split as in the solved form (``v = G_F x_F``, Hessian ``diag(reg I, I)``), so
  a step needs only the Cholesky factor ``L`` of the (6 + k) x (6 + k) matrix
  ``T = C D^-1 C^T`` with ``C = [[G_F, -I], [A_RF, 0]]`` (k active rows, signed to read
  ``a^T x >= b``). Freeing or fixing a weight changes ``T`` by a rank-one term
  ``+-[g_j; a_Rj][g_j; a_Rj]^T / reg``, a row joining appends a row and a column, a row leaving
  removes them: each an O((6 + k)^2) update of ``L``, never a refactorisation.

One step for a violated constraint ``p`` with normal ``n`` (a row, or ``e_j`` for a free weight
below zero): ``mu = T^-1 C_F n_F / reg``; the primal direction ``z_F = (n_F - C_F^T mu) / reg``
(zero on fixed weights, keeping the active rows); the rows' multipliers change by ``-mu_R`` per
unit step and a fixed weight's bound multiplier by ``-r_j``, ``r_j = n_j - [g_j; a_Rj] . mu``.
The step is the smaller of the full one (``p`` is satisfied and joins) and the largest that
keeps every multiplier >= 0 (the constraint whose multiplier reaches zero leaves: a fixed weight
is freed, an active row dropped); among ties the largest ``r`` leaves. ``z . n = |n_F|^2 / reg -
|L^-1 C_F n_F / reg|^2`` is also the new diagonal of ``L`` when ``p`` is a row that joins, and
when it is (close to) zero ``p`` depends on the active constraints.
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

from wholehand.allocation.solvers.implicit_rows import implicit_values, row
from wholehand.allocation.solvers.split_factor import (
    backward,
    column,
    drop_row,
    factor,
    forward,
    rank_one,
)
from wholehand.jit import CACHE

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

OPTIMAL, INFEASIBLE, ITERATION_LIMIT, NUMERICAL = 0, 1, 2, 3
"""Status codes of :func:`dual_active_set` (the last: the factor could not be kept positive
definite even when rebuilt, or the multipliers diverged; the caller solves another way)."""

_DEPENDENT = 1e-9
"""``z . n <= _DEPENDENT |n_F|^2`` means ``p`` depends on the active constraints (the least
true value is about ``|n_F|^2 / (sigma_max^2 + reg)``, the rounding about ``eps |n_F|^2 /
reg``)."""

DIVERGED = 1e9
"""A multiplier past this [N or N*m per unit] means the steps diverge, as they do on an
infeasible problem whose infeasibility rounding hides: the solve stops as :data:`NUMERICAL`."""

REFRESH_EVERY = 64
"""Updates of the factor after which it is rebuilt from scratch at the next new constraint."""


@numba.njit(cache=CACHE, nogil=True)
def dual_active_set(  # noqa: C901 - one compiled solve
    G: FloatArray,
    w: FloatArray,
    reg: float,
    A: FloatArray,
    qr: FloatArray,
    tau: FloatArray,
    W: FloatArray,
    act_idx: IntArray,
    lo: FloatArray,
    hi: FloatArray,
    row_scale: FloatArray,
    free0: BoolArray,
    rows0: npt.NDArray[np.int8],
    tol: float,
    max_iter: int,
) -> tuple[FloatArray, FloatArray, FloatArray, int, int, FloatArray]:
    """Solve the QP of the module docstring.

    The rows are ``A``'s (md, n) dense ones, then the ``mq - kq`` consistency rows
    ``N_u^T W_act`` held implicitly (formed only when one becomes active), ``N_u`` the last
    columns of the Householder ``Q`` of ``qr`` (mq, kq) and ``tau`` (kq,) (LAPACK's ``dgeqrf``
    storage; ``mq = 0`` for none); ``W`` (N, 3, 4) the pyramid edges of every contact in world
    axes, ``act_idx`` (N_act,) the actuated contacts (``mq = 3 N_act``).

    Args:
        G: (6, n) wrench map on the weights.
        w: (6,) constant wrench.
        reg: ridge weight, > 0.
        A, qr, tau, W, act_idx: the rows (above).
        lo, hi: (m,) bounds of every row, ``m = md + mq - kq``.
        row_scale: (m,) > 0, what a row's violation is divided by to compare it with the
            others' when the most violated constraint is chosen (its norm, say); a consistency
            row's entry is set to its norm when the row is formed.
        free0: (n,) weights to start free (a warm start: last cycle's support); the others
            start fixed at zero.
        rows0: (m,) rows to start active (a warm start: last cycle's binding rows): +1 at the
            lower bound, -1 at the upper one, 0 not.
        tol: violation of a row (per unit of its ``row_scale``) or of a bound accepted at the
            end.
        max_iter: steps before giving up.

    Returns:
        ``(x, y, z, status, steps, values)``: (n,) the solution; (m,) the rows' multipliers
        (> 0 at the lower bound, < 0 at the upper one, 0 inactive) and (n,) the bounds' (>= 0),
        with ``H x + G^T w = A^T y + z`` (``H = G^T G + reg I``); :data:`OPTIMAL`,
        :data:`INFEASIBLE`, :data:`ITERATION_LIMIT` or :data:`NUMERICAL`; the steps taken;
        (m,) every row's value at ``x`` (when optimal).
    """
    n = G.shape[1]
    md = A.shape[0]
    m = lo.shape[0]
    mq = qr.shape[0]
    x = np.zeros(n)
    c = np.zeros(n)
    for j in range(n):
        s = 0.0
        for a in range(6):
            s += G[a, j] * w[a]
        c[j] = s
    is_free = free0.copy()
    u_bound = np.zeros(n)  # multipliers of the fixed weights' bounds
    act = np.zeros(m, dtype=np.intp)  # active rows, in their order in T
    Aact = np.empty((m, n))  # their coefficients, signed to read a x >= b
    sign = np.zeros(m)  # by row: +1 a x >= lo active, -1 -a x >= -hi active, 0 inactive
    u_row = np.zeros(m)  # multipliers by row index
    k = 0
    F = np.empty(n, dtype=np.intp)
    nf = 0
    for j in range(n):
        if is_free[j]:
            F[nf] = j
            nf += 1
    L = np.empty((6 + m, 6 + m))  # only its leading lower triangle is ever written or read
    mu = np.empty(6 + m)
    y_last = np.empty(6 + m)
    col = np.empty(6 + m)
    scratch = np.empty(max(mq, 1))
    prow = np.empty(n)
    zf = np.empty(n)
    r_bound = np.zeros(n)
    values = np.empty(m)
    steps = 0
    updates = 0
    inv_sqrt_reg = 1.0 / np.sqrt(reg)

    # A dual-feasible start: the minimiser over the free weights F with the rows of the warm
    # start held at their bounds, T lambda = [-w; b_R]: x_F = C_F^T lambda / reg, the rows'
    # multipliers lambda_R, a fixed weight's -[g_j; a_Rj] . lambda. While one of them is
    # negative, its constraint leaves (a weight is freed, a row dropped), so this ends.
    for r in range(m):
        if rows0[r] != 0:
            act[k] = r
            sign[r] = 1.0 if rows0[r] > 0 else -1.0
            row(A, qr, tau, W, act_idx, r, sign[r], scratch, Aact[k])
            k += 1
    if not factor(L, G, Aact, k, F, nf, reg):
        for q in range(k):  # the warm rows depend on each other here: start without them
            sign[act[q]] = 0.0
        k = 0
        if not factor(L, G, Aact, k, F, nf, reg):
            return x, np.zeros(m), np.zeros(n), NUMERICAL, steps, np.zeros(m)
    while True:
        dim = 6 + k
        for a in range(6):
            mu[a] = -w[a]
        for q in range(k):
            r = act[q]
            mu[6 + q] = sign[r] * (lo[r] if sign[r] > 0.0 else hi[r])
        forward(L, dim, mu)
        backward(L, dim, mu)
        for j in range(n):
            r_bound[j] = 0.0
        for a in range(dim):
            ma = mu[a]
            if a < 6:
                for j in range(n):
                    r_bound[j] += G[a, j] * ma
            else:
                for j in range(n):
                    r_bound[j] += Aact[a - 6, j] * ma
        worst = 0.0
        leave = -1
        leave_row = False
        for j in range(n):
            if is_free[j]:
                x[j] = r_bound[j] / reg
            else:
                x[j] = 0.0
                u_bound[j] = -r_bound[j]
                if -r_bound[j] < worst:
                    worst, leave, leave_row = -r_bound[j], j, False
        for q in range(k):
            u_row[act[q]] = mu[6 + q]
            if mu[6 + q] < worst:
                worst, leave, leave_row = mu[6 + q], q, True
        if leave < 0:
            break
        steps += 1
        if leave_row:
            u_row[act[leave]] = 0.0
            sign[act[leave]] = 0.0
            ok = drop_row(L, dim, 6 + leave, col)
            for q in range(leave, k - 1):
                act[q] = act[q + 1]
                Aact[q] = Aact[q + 1]
            k -= 1
        else:
            column(G, Aact, k, leave, inv_sqrt_reg, col)
            ok = rank_one(L, 0, dim, col, 1.0)
            is_free[leave] = True
            u_bound[leave] = 0.0
            F[nf] = leave
            nf += 1
        if not ok and not factor(L, G, Aact, k, F, nf, reg):
            return x, np.zeros(m), np.zeros(n), NUMERICAL, steps, np.zeros(m)

    status = ITERATION_LIMIT
    while steps < max_iter:
        if updates >= REFRESH_EVERY:
            if not factor(L, G, Aact, k, F, nf, reg):
                status = NUMERICAL
                break
            updates = 0
        # The most violated constraint (dense rows per unit norm, then bounds).
        for r in range(md):
            s = 0.0
            for i in range(nf):
                s += A[r, F[i]] * x[F[i]]
            values[r] = s
        if m > md:
            implicit_values(qr, tau, W, act_idx, x, scratch, values[md:])
        best = tol
        p = -1
        p_bound = False
        p_sign = 0.0
        for r in range(m):
            if sign[r] != 0.0:
                continue
            s = values[r]
            if lo[r] - s > best * row_scale[r]:
                best = (lo[r] - s) / row_scale[r]
                p, p_sign = r, 1.0
            elif s - hi[r] > best * row_scale[r]:
                best = (s - hi[r]) / row_scale[r]
                p, p_sign = r, -1.0
        for i in range(nf):
            j = F[i]
            if -x[j] > best:
                best = -x[j]
                p, p_bound = j, True
        if p < 0:
            status = OPTIMAL
            break
        if p_bound:
            s_p = x[p]
        else:
            s_p = p_sign * (values[p] - (lo[p] if p_sign > 0.0 else hi[p]))
            row(A, qr, tau, W, act_idx, p, p_sign, scratch, prow)
            if p >= md:  # learn the row's norm for the next choices (and cycles)
                row_scale[p] = max(np.sqrt(np.dot(prow, prow)), 1e-300)
        u_p = 0.0
        while True:
            steps += 1
            dim = 6 + k
            # mu = T^-1 C_F n_F / reg (forward half kept in y_last), z_F = (n_F - C_F^T mu) / reg.
            if p_bound:
                column(G, Aact, k, p, 1.0 / reg, mu)
                nn = 1.0
            else:
                nn = 0.0
                for i in range(nf):
                    nn += prow[F[i]] * prow[F[i]]
                for a in range(dim):
                    s = 0.0
                    if a < 6:
                        for i in range(nf):
                            s += G[a, F[i]] * prow[F[i]]
                    else:
                        for i in range(nf):
                            s += Aact[a - 6, F[i]] * prow[F[i]]
                    mu[a] = s / reg
            forward(L, dim, mu)
            yy = 0.0
            for a in range(dim):
                y_last[a] = mu[a]
                yy += mu[a] * mu[a]
            zn = nn / reg - yy  # z . n, and the new diagonal of L if p joins as a row
            backward(L, dim, mu)
            # r_j = n_j - [g_j; a_Rj] . mu for every weight; z_F = r_F / reg on the free ones.
            for j in range(n):
                r_bound[j] = 0.0 if p_bound else prow[j]
            if p_bound:
                r_bound[p] = 1.0
            for a in range(dim):
                ma = mu[a]
                if a < 6:
                    for j in range(n):
                        r_bound[j] -= G[a, j] * ma
                else:
                    for j in range(n):
                        r_bound[j] -= Aact[a - 6, j] * ma
            for i in range(nf):
                zf[i] = r_bound[F[i]] / reg
            # The largest step keeping the multipliers >= 0, and what limits it.
            t1 = np.inf
            drop = -1
            drop_bound = False
            drop_r = 0.0
            for q in range(k):
                rq = mu[6 + q]
                if rq > 0.0:
                    t = max(u_row[act[q]], 0.0) / rq
                    if t < t1 or (t == t1 and rq > drop_r):
                        t1, drop, drop_bound, drop_r = t, q, False, rq
            for j in range(n):
                if not is_free[j] and r_bound[j] > 0.0:
                    t = max(u_bound[j], 0.0) / r_bound[j]
                    if t < t1 or (t == t1 and r_bound[j] > drop_r):
                        t1, drop, drop_bound, drop_r = t, j, True, r_bound[j]
            dependent = not zn > _DEPENDENT * nn
            t2 = np.inf if dependent else -s_p / zn
            if t1 == np.inf and t2 == np.inf:
                status = INFEASIBLE
                break
            t = min(t1, t2)
            if not dependent:
                for i in range(nf):
                    x[F[i]] += t * zf[i]
                s_p += t * zn
            for q in range(k):
                u_row[act[q]] -= t * mu[6 + q]
            for j in range(n):
                if not is_free[j]:
                    u_bound[j] -= t * r_bound[j]
            u_p += t
            updates += 1
            if u_p > DIVERGED:
                # p's multiplier joins the others': together they are (nearly) a ray of the
                # dual, the certificate of infeasibility the caller may check.
                if p_bound:
                    is_free[p] = False
                    u_bound[p] = u_p
                else:
                    act[k] = p
                    sign[p] = p_sign
                    u_row[p] = u_p
                    k += 1
                status = NUMERICAL
                break
            ok = True
            if t == t2:  # p joins the active set
                if p_bound:
                    column(G, Aact, k, p, inv_sqrt_reg, col)
                    ok = rank_one(L, 0, dim, col, -1.0)
                    is_free[p] = False
                    x[p] = 0.0
                    u_bound[p] = u_p
                    for i in range(nf):
                        if F[i] == p:
                            F[i] = F[nf - 1]
                            break
                    nf -= 1
                else:
                    for a in range(dim):
                        L[dim, a] = y_last[a]
                    L[dim, dim] = np.sqrt(zn)
                    act[k] = p
                    Aact[k] = prow
                    sign[p] = p_sign
                    u_row[p] = u_p
                    k += 1
                if not ok and not factor(L, G, Aact, k, F, nf, reg):
                    status = NUMERICAL
                break
            # A constraint leaves; the same p goes on.
            if drop_bound:
                column(G, Aact, k, drop, inv_sqrt_reg, col)
                ok = rank_one(L, 0, dim, col, 1.0)
                is_free[drop] = True
                u_bound[drop] = 0.0
                x[drop] = 0.0
                F[nf] = drop
                nf += 1
            else:
                r = act[drop]
                u_row[r] = 0.0
                sign[r] = 0.0
                ok = drop_row(L, dim, 6 + drop, col)
                for q in range(drop, k - 1):
                    act[q] = act[q + 1]
                    Aact[q] = Aact[q + 1]
                k -= 1
            if not ok and not factor(L, G, Aact, k, F, nf, reg):
                status = NUMERICAL
                break
            if steps >= max_iter:
                break
        if status == INFEASIBLE or status == NUMERICAL:
            break
    y = np.zeros(m)
    for q in range(k):
        y[act[q]] = sign[act[q]] * u_row[act[q]]
    z = np.zeros(n)
    for j in range(n):
        if not is_free[j]:
            z[j] = u_bound[j]
    return x, y, z, status, steps, values
