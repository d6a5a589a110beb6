"""The allocation's compiled kernels (the problem's terms, the screening loop, the warm start)
against their definitions in plain numpy."""

from __future__ import annotations

import numpy as np
import pytest

from wholehand.allocation.kernels import consistency_rows, edge_forces, structured_terms
from wholehand.allocation.problem import friction_edges
from wholehand.allocation.screening_kernels import (
    active_of,
    active_vector,
    at_bounds,
    priced_edges,
    selection,
    solved_rows,
)
from wholehand.allocation.warm_start import WarmStart, rows_of_joints


def _case(seed: int, n: int, n_v: int = 16):
    rng = np.random.default_rng(seed)
    n_world = rng.normal(size=(n, 3))
    n_world /= np.linalg.norm(n_world, axis=1, keepdims=True)
    n_world[0] = (0.0, 0.0, -1.0)  # the frame construction's seam
    p_world = rng.normal(size=(n, 3)) * 0.05
    J = rng.normal(size=(n, 3, n_v)) * 0.1
    J[:, :, 3] = 0.0  # a joint no contact moves
    return n_world, p_world, rng.normal(size=3) * 0.05, J


@pytest.mark.parametrize("seed", range(4))
def test_terms_match_their_numpy_definitions(seed: int) -> None:
    n = 9
    n_world, p_world, p_com, J = _case(seed, n)
    E = friction_edges(0.7)
    actuated = np.zeros(n, dtype=bool)
    actuated[[0, 2, 3, 7]] = True
    dofs = np.array([1, 3, 4, 9, 15], dtype=np.intp)
    tau_max = np.array([1.0, 1.0, np.inf, 0.5, 2.0])  # joint 4: no limit, so no torque row
    wRc, r, W, G, act_idx, J_act, moved, torque_rows, T = structured_terms(
        n_world, p_world, p_com, E, J, actuated, dofs, tau_max
    )

    # Frames: orthonormal, right-handed, first column into the object.
    np.testing.assert_allclose(
        np.einsum("nji,njk->nik", wRc, wRc), np.broadcast_to(np.eye(3), (n, 3, 3)), atol=1e-14
    )
    np.testing.assert_allclose(np.linalg.det(wRc), 1.0, atol=1e-14)
    np.testing.assert_array_equal(wRc[:, :, 0], -n_world)
    np.testing.assert_array_equal(r, p_world - p_com)
    np.testing.assert_allclose(W, wRc @ E, rtol=0, atol=1e-15)
    # Wrench columns: [w; r x w] of each edge.
    for i in range(n):
        for e in range(4):
            col = G[:, 4 * i + e]
            np.testing.assert_array_equal(col[:3], W[i, :, e])
            np.testing.assert_allclose(col[3:], np.cross(r[i], W[i, :, e]), atol=1e-16)
    # The actuated contacts' Jacobian rows on the commanded joints, copied.
    np.testing.assert_array_equal(act_idx, [0, 2, 3, 7])
    np.testing.assert_array_equal(J_act, J[act_idx][:, :, dofs].reshape(-1, dofs.size))
    np.testing.assert_array_equal(moved, [0, 2, 3, 4])  # joint 3 (position 1): moved by none
    np.testing.assert_array_equal(torque_rows, [0, 3, 4])  # and joint 4 has no limit
    # Torques: J_i^T W_i for actuated contacts, zero columns for the others.
    expected = np.zeros((dofs.size, n, 4))
    for i in act_idx:
        expected[:, i, :] = J[i][:, dofs].T @ W[i]
    expected = expected.reshape(dofs.size, -1)[torque_rows]
    np.testing.assert_allclose(T, expected, rtol=0, atol=1e-15)


def test_edge_forces_are_the_edges_weighted() -> None:
    n_world, p_world, p_com, J = _case(5, 6)
    E = friction_edges(0.5)
    W = structured_terms(
        n_world, p_world, p_com, E, J, np.ones(6, dtype=bool), np.arange(16), np.ones(16)
    )[2]
    lam = np.random.default_rng(1).random(24)
    rows = np.array([4, 1], dtype=np.intp)
    expected = np.einsum("nij,nj->ni", W[rows], lam.reshape(-1, 4)[rows])
    np.testing.assert_allclose(edge_forces(W, lam, rows), expected, rtol=0, atol=1e-15)


def test_consistency_rows_are_basis_components_times_edges() -> None:
    rng = np.random.default_rng(6)
    n, k = 7, 5
    W = rng.normal(size=(n, 3, 4))
    act_idx = np.array([1, 2, 6], dtype=np.intp)
    Nc = rng.normal(size=(act_idx.size, 3, k))
    rows = consistency_rows(Nc, W, act_idx)
    assert rows.shape == (k, 4 * n)
    for j in range(k):
        lam = rng.random(4 * n)
        f_act = np.einsum("nce,ne->nc", W[act_idx], lam.reshape(-1, 4)[act_idx])
        # Row j applied to lambda is basis column j applied to the actuated contacts' forces.
        assert rows[j] @ lam == pytest.approx(np.sum(Nc[:, :, j] * f_act), rel=1e-12)
    not_act = np.setdiff1d(np.arange(n), act_idx)
    assert np.all(rows.reshape(k, n, 4)[:, not_act] == 0.0)


def test_solved_rows_stack_the_wrench_squeeze_torque_and_consistency_rows() -> None:
    rng = np.random.default_rng(9)
    nl = 8
    G, T, N = rng.normal(size=(6, nl)), rng.normal(size=(5, nl)), rng.normal(size=(2, nl))
    w_ext, sel = rng.normal(size=6), np.array([4, 1], dtype=np.intp)
    t_lo, t_hi = -rng.random(5), rng.random(5)  # bounds of every torque row
    every = np.arange(nl, dtype=np.intp)
    A, lower, upper = solved_rows(G, T, sel, N, w_ext, 10.0, t_lo, t_hi, 0.5, every)
    expected = np.zeros((11, nl + 6))
    expected[:6, :nl], expected[:6, nl:] = G, -np.eye(6)  # G lambda - w
    expected[6, :nl] = 1.0  # sum(lambda)
    expected[7:9, :nl], expected[9:, :nl] = T[sel], N
    np.testing.assert_array_equal(A, expected)
    np.testing.assert_array_equal(lower, np.r_[-w_ext, 10.0, t_lo[sel], -0.5, -0.5])
    np.testing.assert_array_equal(upper, np.r_[-w_ext, np.inf, t_hi[sel], 0.5, 0.5])
    # Some edge weights only: their columns, then the wrench's.
    edges = np.array([1, 5, 6], dtype=np.intp)
    A_e, lower_e, upper_e = solved_rows(G, T, sel, N, w_ext, 10.0, t_lo, t_hi, 0.5, edges)
    np.testing.assert_array_equal(A_e, np.hstack((expected[:, edges], expected[:, nl:])))
    np.testing.assert_array_equal(lower_e, lower)
    np.testing.assert_array_equal(upper_e, upper)


def test_priced_edges_are_the_left_out_columns_with_a_negative_multiplier() -> None:
    """Each left-out edge's price is its column of the full rows times the multipliers."""
    rng = np.random.default_rng(10)
    nl = 12
    G, T, N = rng.normal(size=(6, nl)), rng.normal(size=(5, nl)), rng.normal(size=(3, nl))
    sel = np.array([0, 3], dtype=np.intp)
    every = np.arange(nl, dtype=np.intp)
    A = solved_rows(G, T, sel, N, np.zeros(6), 1.0, -np.ones(5), np.ones(5), 1.0, every)[0]
    y = rng.normal(size=A.shape[0])
    price = A[:, :nl].T @ y
    in_problem = rng.random(nl) < 0.4
    got = priced_edges(G, T, sel, N, y, in_problem, 1e-9)
    np.testing.assert_array_equal(got, np.flatnonzero((price < -1e-9) & ~in_problem))
    assert got.size > 0  # the case checks something


def test_selection_is_a_mask_and_its_sorted_indices() -> None:
    mask, idx = selection(np.array([4, 1, 4, 9, 0], dtype=np.intp), 6)
    np.testing.assert_array_equal(mask, [True, True, False, False, True, False])
    np.testing.assert_array_equal(idx, [0, 1, 4])
    mask, idx = selection(np.zeros(0, dtype=np.intp), 3)
    assert not mask.any() and idx.size == 0


def test_daqp_bounds_clip_infinities_and_keep_nan() -> None:
    from wholehand.allocation.solvers.daqp_solver import _bounds

    ub, upper = np.array([np.inf, 2.0]), np.array([-1.0, np.nan])
    lb, lower = np.array([0.0, -np.inf]), np.array([-np.inf, 3.0])
    bu, bl = _bounds(ub, upper, lb, lower, 1e30)
    np.testing.assert_array_equal(bu, np.minimum(np.r_[ub, upper], 1e30))
    np.testing.assert_array_equal(bl, np.maximum(np.r_[lb, lower], -1e30))


def test_rows_at_bounds_within_the_relative_and_absolute_slack() -> None:
    values = np.array([1.0, -0.9999995, 0.5, np.nan, -2.0])
    limits = np.ones(5)
    np.testing.assert_array_equal(at_bounds(values, limits, 1e-6, 1e-9), [0, 1, 4])
    np.testing.assert_array_equal(at_bounds(values, limits, 0.0, 0.0), [0, 4])


def test_rows_of_joints_are_the_torque_rows_of_those_joints() -> None:
    dofs = np.array([0, 2, 3, 5, 8], dtype=np.intp)
    torque_rows = np.array([0, 1, 3, 4], dtype=np.intp)  # joints 0, 2, 5, 8 have rows
    joints = np.array([8, 3, 2, 11], dtype=np.intp)  # 3: no row; 11: beyond n_v
    got = rows_of_joints(joints, 9, dofs, torque_rows)
    np.testing.assert_array_equal(got, [1, 3])  # rows of joints 2 and 8, by position
    assert rows_of_joints(np.zeros(0, dtype=np.intp), 9, dofs, torque_rows).size == 0


def _nearest_on_link(p, link, q, q_link, radius):
    """The match's definition, one contact at a time."""
    out = np.full(len(p), -1)
    for i in range(len(p)):
        same = np.flatnonzero(q_link == link[i])
        if same.size:
            d = np.linalg.norm(q[same] - p[i], axis=1)
            if d.min() <= radius:
                out[i] = same[np.argmin(d)]
    return out


@pytest.mark.parametrize("seed", range(3))
def test_warm_start_matches_each_contact_to_the_nearest_on_its_link(seed: int) -> None:
    rng = np.random.default_rng(seed)
    q = rng.random((12, 3)) * 0.05
    q_link = rng.integers(0, 4, 12).astype(np.intp)
    p = np.vstack((q[[3, 3, 7]] + 0.001, rng.random((4, 3)) * 0.05))  # two near contact 3
    link = np.r_[q_link[[3, 3, 7]], rng.integers(0, 5, 4)].astype(np.intp)
    warm = WarmStart(match_radius=0.005, p_world=q, link=q_link)
    got = warm.match(p, link)
    np.testing.assert_array_equal(got, _nearest_on_link(p, link, q, q_link, 0.005))
    np.testing.assert_array_equal(got[:3], [3, 3, 7])
    # Same links in the same order and within the radius: the identity; one moved away: not.
    np.testing.assert_array_equal(warm.match(q + 0.001, q_link), np.arange(12))
    moved = q.copy()
    moved[5] += 0.01
    np.testing.assert_array_equal(
        warm.match(moved, q_link), _nearest_on_link(moved, q_link, q, q_link, 0.005)
    )
    assert warm.match(moved, q_link)[5] != 5
    assert (WarmStart().match(p, link) == -1).all()  # nothing to continue


def test_active_set_by_identity_and_back() -> None:
    """A round's multipliers -> the active set by identity (signs, left-out edges at their
    bound) -> the guess of a problem with other edges and rows, against the definitions."""
    rng = np.random.default_rng(11)
    nl, n_t, n_null = 12, 5, 4
    edge_sel = np.array([0, 2, 3, 7, 11], dtype=np.intp)
    t_sel, n_sel = np.array([1, 4], dtype=np.intp), np.array([2], dtype=np.intp)
    m = 7 + t_sel.size + n_sel.size
    duals = rng.normal(size=edge_sel.size + 6 + m)
    duals[[1, 4]] = 0.0  # inactive bounds
    edges, squeeze, torque, null = active_of(duals, nl, edge_sel, t_sel, n_sel, n_t, n_null)
    sign = np.sign(duals).astype(np.intp)
    want_edges = np.full(nl, -1)
    want_edges[edge_sel] = sign[: edge_sel.size]
    rows = sign[edge_sel.size + 6 :]  # after the wrench variables' bounds
    np.testing.assert_array_equal(edges, want_edges)
    assert squeeze == rows[6]
    want_torque, want_null = np.zeros(n_t, int), np.zeros(n_null, int)
    want_torque[t_sel], want_null[n_sel] = rows[7:9], rows[9:]
    np.testing.assert_array_equal(torque, want_torque)
    np.testing.assert_array_equal(null, want_null)
    # The next round: all edges, more rows.
    t_next, n_next = np.array([0, 1, 4], dtype=np.intp), np.array([2, 3], dtype=np.intp)
    every = np.arange(nl, dtype=np.intp)
    vector = active_vector(edges, squeeze, torque, null, every, t_next, n_next)
    want = np.r_[want_edges, np.zeros(12, int), squeeze, torque[t_next], null[n_next]]
    np.testing.assert_array_equal(vector, want)


def test_daqp_start_flags_follow_the_guess_and_keep_equalities_active() -> None:
    from wholehand.allocation.solvers.daqp_solver import _ACTIVE, _IMMUTABLE, _LOWER, _start_flags

    n, n_eq = 3, 2
    sense = np.zeros(n + 4, dtype=np.intc)
    active = np.array([1, -1, 0, 1, -1, 0, 1], dtype=np.intp)  # a guess on the equalities too
    flags = _start_flags(sense, active, n, n_eq)
    eq = _ACTIVE | _IMMUTABLE
    np.testing.assert_array_equal(flags, [_ACTIVE, _ACTIVE | _LOWER, 0, eq, eq, 0, _ACTIVE])
    assert (sense == 0).all()  # a copy
