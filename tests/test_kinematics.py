"""Forward kinematics, batched transforms and point Jacobians against finite differences."""

from __future__ import annotations

import copy as copy_module

import numpy as np
import pinocchio as pin
import pytest

from wholehand.errors import ConfigError
from wholehand.models.hand import load_hand
from wholehand.models.kinematics import HandKinematics
from wholehand.models.poses import pose_from_xyz_rpy


@pytest.fixture
def state(allegro):
    rng = np.random.default_rng(3)
    q = allegro.neutral() + 0.2 * rng.standard_normal(allegro.nq)
    wMb = pose_from_xyz_rpy([0.1, -0.2, 0.3], [0.3, -0.2, 1.0])
    kin = HandKinematics(allegro)
    kin.update(q, wMb)
    return kin, q, wMb, rng


def test_transformed_samples_match_pinocchio_frames(state, allegro):
    kin, q, wMb, _ = state
    i = allegro.link_index("link_15.0_tip")
    rows = allegro.samples.link == i
    p_world = kin.transform_points(allegro.samples.p_joint[rows], allegro.samples.joint[rows])
    jid = int(allegro.link_joint[i])
    data = allegro.model.createData()
    pin.forwardKinematics(allegro.model, data, q)
    expected = [
        (wMb @ data.oMi[jid].homogeneous @ np.r_[p, 1.0])[:3] for p in allegro.samples.p_joint[rows]
    ]
    np.testing.assert_allclose(p_world, expected, atol=1e-12)


def test_points_and_directions_to_joint_frames_and_back_match_pinocchio(state, allegro):
    kin, q, wMb, rng = state
    joint = rng.integers(1, allegro.model.njoints, size=7).astype(np.intp)
    p, n = rng.normal(scale=0.1, size=(7, 3)), rng.normal(size=(7, 3))
    p_joint, n_joint = kin.to_joint_frames(p, n, joint)
    data = allegro.model.createData()
    pin.forwardKinematics(allegro.model, data, q)
    for i, j in enumerate(joint):
        wMj = wMb @ data.oMi[int(j)].homogeneous
        np.testing.assert_allclose(wMj[:3, :3] @ p_joint[i] + wMj[:3, 3], p[i], atol=1e-12)
        np.testing.assert_allclose(wMj[:3, :3] @ n_joint[i], n[i], atol=1e-12)
    back = kin.from_joint_frames(p_joint, n_joint, joint)
    np.testing.assert_allclose(back[0], p, atol=1e-12)
    np.testing.assert_allclose(back[1], n, atol=1e-12)
    # Other layouts (a transposed view, a read-only array) give the same values.
    p_view, n_ro = np.ascontiguousarray(p.T).T, n.copy()
    n_ro.setflags(write=False)
    got = kin.to_joint_frames(p_view, n_ro, joint)
    np.testing.assert_array_equal(got[0], p_joint)
    np.testing.assert_array_equal(got[1], n_joint)


def test_point_jacobians_match_finite_differences(state, allegro):
    kin, q, wMb, rng = state
    idx = rng.choice(len(allegro.samples), 60, replace=False)
    p_joint, joint = allegro.samples.p_joint[idx], allegro.samples.joint[idx]
    p0 = kin.transform_points(p_joint, joint)
    J = kin.point_jacobians(joint, p0)
    eps = 1e-7
    J_fd = np.zeros_like(J)
    for k in range(allegro.nv):
        dq = np.zeros(allegro.nv)
        dq[k] = eps
        kin.update(q + dq, wMb)
        J_fd[:, :, k] = (kin.transform_points(p_joint, joint) - p0) / eps
    np.testing.assert_allclose(J, J_fd, atol=1e-6)


def test_points_on_the_palm_do_not_move_with_the_joints(state, allegro):
    kin, _, _, _ = state
    rows = np.flatnonzero(allegro.samples.link == allegro.link_index("palm_link"))[:5]
    p = kin.transform_points(allegro.samples.p_joint[rows], allegro.samples.joint[rows])
    assert np.all(kin.point_jacobians(allegro.samples.joint[rows], p) == 0.0)


def test_bad_configuration_is_rejected(allegro):
    kin = HandKinematics(allegro)
    with pytest.raises(ConfigError, match="q has shape"):
        kin.update(np.zeros(3))
    with pytest.raises(ConfigError, match="NaN"):
        kin.update(np.full(allegro.nq, np.nan))
    with pytest.raises(ConfigError, match="wMb"):
        kin.update(allegro.neutral(), np.ones((4, 4)))


@pytest.mark.parametrize("name", ["allegro_right", "robotis_hx5_d20_right"])
def test_joint_placements_are_pinocchios(name):
    hand = load_hand(name)
    kin = HandKinematics(hand)
    assert kin._placements is not None  # the strided views, on this Pinocchio
    copy = copy_module.deepcopy(kin)
    assert copy._placements is not None
    slow = HandKinematics(hand)
    slow._placements = None  # read one by one
    data = hand.model.createData()
    rng = np.random.default_rng(2)
    for _ in range(5):
        q = rng.uniform(hand.q_lower, hand.q_upper)
        for k in (kin, copy, slow):
            k.update(q)
        pin.forwardKinematics(hand.model, data, q)
        expected = np.array([M.homogeneous for M in data.oMi])
        for k in (kin, copy, slow):
            np.testing.assert_array_equal(k.bRj, expected[:, :3, :3])
            np.testing.assert_array_equal(k.bp_j, expected[:, :3, 3])
        copy.update(q + rng.normal(scale=0.1, size=q.shape))  # the copy has its own data
        np.testing.assert_array_equal(kin.bRj, expected[:, :3, :3])
