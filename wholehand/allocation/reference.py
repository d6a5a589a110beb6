"""Reference forms of the allocation QP, for tests and A/B comparisons (never the control loop).

:func:`solved_problem` is the full QP in the form the allocator solves (every row, no screening);
:func:`direct_problem` is the paper's form on local contact forces. Both go to any
:mod:`qpsolvers` solver, so their optima check the allocator's.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as spa

from wholehand.allocation.problem import N_WRENCH, AllocationQP

if TYPE_CHECKING:
    import qpsolvers


def solved_problem(qp: AllocationQP, sparse: bool = False) -> qpsolvers.Problem:
    """The full QP in the solved (edge, wrench-split) form as a :class:`qpsolvers.Problem`.

    ``x = [lambda; w]``; ``P = diag(reg, ..., reg, 1, ..., 1)``, ``q = 0``; equality
    ``G_lam lambda - w = -w_ext``; inequalities ``-sum(lambda) <= -f_n_min``, ``+-(tau_bias +
    T_lam lambda) <= tau_max``, ``+-C lambda <= eps_margin``; bounds ``lambda >= 0``.

    Args:
        sparse: Return CSC matrices (for sparse solvers) instead of dense arrays.
    """
    import qpsolvers

    nl, n = qp.n_lambda, qp.n_x
    P = np.concatenate((np.full(nl, qp.params.reg), np.ones(N_WRENCH)))
    A = np.hstack((qp.G_lam, -np.eye(N_WRENCH)))
    rows = [-np.ones((1, nl))]
    h = [np.array([-qp.params.f_n_min])]
    if qp.torque_rows.size:
        lower, upper = qp.torque_bounds()
        rows += [qp.T_lam, -qp.T_lam]
        h += [upper, -lower]
    if qp.n_null and np.isfinite(qp.params.eps_margin):
        C = qp.null_rows(np.arange(qp.n_null))
        rows += [C, -C]
        h += [np.full(qp.n_null, qp.params.eps_margin)] * 2
    Gi = np.vstack(rows)
    Gi = np.hstack((Gi, np.zeros((Gi.shape[0], N_WRENCH))))
    hv = np.concatenate(h)
    lb = np.concatenate((np.zeros(nl), np.full(N_WRENCH, -np.inf)))
    ub = np.full(n, np.inf)
    if sparse:
        return qpsolvers.Problem(
            spa.diags(P, format="csc"),
            np.zeros(n),
            spa.csc_matrix(Gi),
            hv,
            spa.csc_matrix(A),
            -qp.w_ext,
            lb,
            ub,
        )
    return qpsolvers.Problem(np.diag(P), np.zeros(n), Gi, hv, A, -qp.w_ext, lb, ub)


def direct_problem(qp: AllocationQP, reg: float | None = None) -> qpsolvers.Problem:
    """The paper's form on local forces ``f`` (3N,) as a dense :class:`qpsolvers.Problem`.

    ``min 1/2 ||G f + w_ext||^2 + reg/2 ||f||^2`` subject to ``f_n >= 0`` (bounds), four
    friction rows per contact, the minimum squeeze, the torque rows and the consistency rows
    (same ``N_u`` as ``qp``). A reference for tests and A/B comparisons, not used in the control
    loop.

    Args:
        qp: Structured problem of the cycle.
        reg: Ridge weight on ``f`` (default ``qp.params.reg``).
    """
    import qpsolvers

    p = qp.params
    n = qp.n_contacts
    reg = p.reg if reg is None else reg
    P = qp.G.T @ qp.G + reg * np.eye(3 * n)
    fric = np.zeros((n, 4, n, 3))
    signs = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, 1.0], [-1.0, -1.0]])
    i = np.arange(n)
    fric[i, :, i, 0] = -p.mu
    fric[i, :, i, 1] = signs[:, 0]
    fric[i, :, i, 2] = signs[:, 1]
    rows = [fric.reshape(4 * n, 3 * n)]
    h = [np.zeros(4 * n)]
    s = np.zeros((1, n, 3))
    s[0, :, 0] = -1.0
    rows.append(s.reshape(1, -1))
    h.append(np.array([-p.f_n_min]))
    # f_act (3 N_act,) = Rb f with Rb block-diagonal of the actuated contacts' frames.
    blocks = np.zeros((qp.act_idx.size, 3, n, 3))
    blocks[np.arange(qp.act_idx.size), :, qp.act_idx, :] = qp.wRc[qp.act_idx]
    Rb = blocks.reshape(3 * qp.act_idx.size, 3 * n)
    if qp.torque_rows.size:
        T = (qp.J_act.T @ Rb)[qp.torque_rows]
        lower, upper = qp.torque_bounds()
        rows += [T, -T]
        h += [upper, -lower]
    if qp.n_null and np.isfinite(p.eps_margin):
        assert qp.null is not None
        C = qp.null.basis().T @ Rb
        rows += [C, -C]
        h += [np.full(qp.n_null, p.eps_margin)] * 2
    lb = np.tile([0.0, -np.inf, -np.inf], n)
    q = qp.G.T @ qp.w_ext
    return qpsolvers.Problem(P, q, np.vstack(rows), np.concatenate(h), lb=lb)


def paper_lab_problem(qp: AllocationQP) -> qpsolvers.Problem:
    """The form the paper's lab solves with OSQP: local forces ``f`` (3N,) and the residual
    wrench ``w`` (6,) as variables, ``w = G f + w_ext`` as six equality rows, ``min 1/2
    ||w||^2 + reg/2 ||f||^2``, and the rows of :func:`direct_problem` on ``f`` (friction,
    squeeze, torques, consistency); sparse, for OSQP. The baseline of ``wholehand bench
    allocate``, never used in the control loop.
    """
    import qpsolvers

    direct = direct_problem(qp)
    assert direct.G is not None and direct.h is not None and direct.lb is not None
    n_f = 3 * qp.n_contacts
    P = spa.diags(np.r_[np.full(n_f, qp.params.reg), np.ones(N_WRENCH)], format="csc")
    G_in = spa.hstack([spa.csc_matrix(direct.G), spa.csc_matrix((direct.G.shape[0], N_WRENCH))])
    A_eq = spa.hstack([spa.csc_matrix(qp.G), -spa.eye(N_WRENCH)], format="csc")
    lb = np.r_[direct.lb, np.full(N_WRENCH, -np.inf)]
    q = np.zeros(n_f + N_WRENCH)
    return qpsolvers.Problem(P, q, G_in.tocsc(), direct.h, A_eq, -qp.w_ext, lb)
