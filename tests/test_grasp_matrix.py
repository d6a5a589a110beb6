"""Contact frames and grasp matrices against hand-derived values (wholehand.allocation.grasp)."""

from __future__ import annotations

import numpy as np
import pytest

from wholehand.allocation.grasp import (
    contact_frames,
    grasp_matrix,
    grasp_matrix_world,
    local_to_world,
    skew,
    wrench_map,
)


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_frames_are_right_handed_orthonormal_with_inward_normal() -> None:
    rng = np.random.default_rng(0)
    n = np.vstack(
        [
            _unit(rng, 500),
            np.eye(3),
            -np.eye(3),
            [[0.0, 0.0, 1.0 - 1e-16], [1e-300, 0.0, -1.0]],
            [[0.6, 0.0, 1e-17], [0.0, -0.8, -1e-17]],
        ]
    )
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    R = contact_frames(n)
    assert np.isfinite(R).all()
    np.testing.assert_allclose(
        R.transpose(0, 2, 1) @ R, np.broadcast_to(np.eye(3), R.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(R[:, :, 0], -n, atol=1e-15)  # local normal points into the object
    np.testing.assert_allclose(np.cross(R[:, :, 0], R[:, :, 1]), R[:, :, 2], atol=1e-12)
    np.testing.assert_array_equal(contact_frames(n), R)  # deterministic


def test_pushing_normal_force_acts_against_outward_normal() -> None:
    n = np.array([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0]])
    f_world = local_to_world(contact_frames(n), np.array([[2.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
    np.testing.assert_allclose(f_world, [[0.0, 0.0, -2.0], [-0.6, -0.8, 0.0]], atol=1e-15)


def test_frames_hand_derived_for_axis_normals() -> None:
    # Duff et al. 2017 with e_n = -n: worked by hand.
    R = contact_frames(np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
    expected = np.array(
        [
            # columns: e_n, t1, t2
            [[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]],
            [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]],
            [[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]],
        ]
    )
    np.testing.assert_allclose(R, expected, atol=1e-15)


def test_grasp_matrix_equals_hand_computed() -> None:
    c = np.array([0.1, 0.2, 0.3])
    p = c + np.array([[0.05, 0.0, 0.0], [-0.05, 0.0, 0.0], [0.0, 0.0, 0.04]])
    n = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    G, _ = grasp_matrix(p, n, c)
    # Column j of contact i: [d; r_i x d] with d the frame axis (see the frames above).
    # c1 r=(.05,0,0): e_n=(-1,0,0) t1=(0,0,1) t2=(0,1,0)
    # c2 r=(-.05,0,0): e_n=(1,0,0) t1=(0,0,-1) t2=(0,1,0)
    # c3 r=(0,0,.04): e_n=(0,0,-1) t1=(1,0,0) t2=(0,-1,0)
    expected = np.array(
        [
            [-1, 0, 0, 1, 0, 0, 0, 1, 0],
            [0, 0, 1, 0, 0, 1, 0, 0, -1],
            [0, 1, 0, 0, -1, 0, -1, 0, 0],
            [0, 0, 0, 0, 0, 0, 0, 0, 0.04],
            [0, -0.05, 0, 0, -0.05, 0, 0, 0.04, 0],
            [0, 0, 0.05, 0, 0, -0.05, 0, 0, 0],
        ],
        dtype=float,
    )
    np.testing.assert_allclose(G, expected, atol=1e-15)
    # Antipodal unit pushes cancel.
    f = np.array([1.0, 0, 0, 1.0, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(G @ f, 0.0, atol=1e-15)


def test_grasp_matrix_world_hand_computed() -> None:
    c = np.array([1.0, -1.0, 0.5])
    p = c + np.array([[0.0, 0.02, 0.0], [0.01, 0.0, -0.03]])
    Gw = grasp_matrix_world(p, c)
    expected = np.zeros((6, 6))
    expected[:3, :3] = expected[:3, 3:] = np.eye(3)
    expected[3:, :3] = [[0, 0, 0.02], [0, 0, 0], [-0.02, 0, 0]]
    expected[3:, 3:] = [[0, 0.03, 0], [-0.03, 0, -0.01], [0, 0.01, 0]]
    np.testing.assert_allclose(Gw, expected, atol=1e-15)


@pytest.mark.parametrize("seed", range(3))
def test_grasp_matrix_matches_explicit_wrench_sum(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n_c = 7
    p, n, c = rng.normal(size=(n_c, 3)), _unit(rng, n_c), rng.normal(size=3)
    f = rng.normal(size=(n_c, 3))
    G, R = grasp_matrix(p, n, c)
    f_world = local_to_world(R, f)
    w = np.concatenate([f_world.sum(0), np.cross(p - c, f_world).sum(0)])
    np.testing.assert_allclose(G @ f.ravel(), w, atol=1e-12)
    np.testing.assert_allclose(grasp_matrix_world(p, c) @ f_world.ravel(), w, atol=1e-12)
    V = rng.normal(size=(n_c, 3, 4))
    a = rng.normal(size=(n_c, 4))
    fv = np.einsum("nij,nj->ni", V, a)
    wv = np.concatenate([fv.sum(0), np.cross(p - c, fv).sum(0)])
    np.testing.assert_allclose(wrench_map(p - c, V) @ a.ravel(), wv, atol=1e-12)


def test_skew_is_cross_product() -> None:
    rng = np.random.default_rng(3)
    v, u = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", skew(v), u), np.cross(v, u), atol=1e-14)


def test_empty_contact_set() -> None:
    G, R = grasp_matrix(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(3))
    assert G.shape == (6, 0) and R.shape == (0, 3, 3)
