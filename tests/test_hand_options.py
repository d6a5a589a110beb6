"""hand.toml options for real hands: locked joints, excluded links, outer-surface sampling."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from toy_hand import KNUCKLE, toy_urdf, write_toy_hand
from wholehand_plugins.mujoco.backend import MujocoBackend

from wholehand.backends.command import Command
from wholehand.errors import ConfigError
from wholehand.models.hand import load_hand
from wholehand.models.objects import ObjectModel

PALM = {"palm_xyz": (0.01, 0.02, 0.03), "palm_rpy": (0.2, 0.1, -0.3)}


def _lock(folder, table: str):
    path = folder / "hand.toml"
    path.write_text(path.read_text().replace("[grasping]", f"[joints]\n{table}\n\n[grasping]"))
    return folder


def test_a_locked_wrist_is_a_fixed_joint_at_its_value(tmp_path):
    hand = load_hand(
        _lock(write_toy_hand(tmp_path / "toy", wrist=True, **PALM), "locked = { wrist = 0.3 }")
    )
    assert "wrist" not in hand.joint_names and hand.nq == 5
    # The same links, posed by the full URDF model with the wrist at 0.3 rad.
    (tmp_path / "full.urdf").write_text(toy_urdf(wrist=True, **PALM))
    full = pin.buildModelFromUrdf(str(tmp_path / "full.urdf"))
    q_full = pin.neutral(full)
    q_full[full.joints[full.getJointId("wrist")].idx_q] = 0.3
    q = hand.neutral()
    for name in hand.joint_names:
        i = hand.model.joints[hand.model.getJointId(name)].idx_q
        q_full[full.joints[full.getJointId(name)].idx_q] = q[i]
    data, data_full = hand.model.createData(), full.createData()
    pin.framesForwardKinematics(hand.model, data, q)
    pin.framesForwardKinematics(full, data_full, q_full)
    for link in hand.link_names:
        np.testing.assert_allclose(
            data.oMf[hand.model.getFrameId(link)].homogeneous,
            data_full.oMf[full.getFrameId(link)].homogeneous,
            atol=1e-12,
        )
    # MuJoCo welds the wrist at the same value: every link body where Pinocchio puts it, and
    # no wrist degree of freedom (5 hand joints and the object's free joint).
    backend = MujocoBackend(hand, ObjectModel.sphere(0.03, mass=0.1))
    assert backend.model.njnt == 6
    backend.set_kinematic_hand(q)
    for i, frame in enumerate(hand.link_frame):
        wMl = hand.wMb @ data.oMf[int(frame)].homogeneous
        body = backend.scene.link_body[i]
        np.testing.assert_allclose(backend.data.xpos[body], wMl[:3, 3], atol=1e-12)
        np.testing.assert_allclose(backend.data.xmat[body].reshape(3, 3), wMl[:3, :3], atol=1e-12)
    backend.apply(Command.torques(np.full(hand.nv, 0.05)))
    backend.step(0.05)
    palm = backend.scene.link_body[hand.link_index("palm")]
    np.testing.assert_allclose(
        backend.data.xmat[palm].reshape(3, 3),
        hand.wMb[:3, :3] @ data.oMf[hand.model.getFrameId("palm")].rotation,
        atol=1e-12,
    )


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ("locked = { elbow = 0.0 }", "locked joint 'elbow' is not a moving joint"),
        ("locked = { wrist = 2.0 }", r"locked.wrist = 2.0 is outside the joint's limits \[-1, 1\]"),
        ('locked = { wrist = "up" }', "locked.wrist must be a number"),
        ('locked = { wrist = 0.0 }\nactuated = ["wrist"]', "joint 'wrist' is locked"),
    ],
)
def test_bad_locked_joints_are_named(tmp_path, table, message):
    folder = _lock(write_toy_hand(tmp_path / "toy", wrist=True), table)
    with pytest.raises(ConfigError, match=message):
        load_hand(folder)


def test_an_excluded_forearm_gets_no_samples(tmp_path):
    kept = load_hand(write_toy_hand(tmp_path / "a", forearm=True))
    assert "forearm" in kept.link_names
    hand = load_hand(write_toy_hand(tmp_path / "b", 'excluded_links = ["forearm"]', forearm=True))
    assert "forearm" not in hand.link_names
    assert len(hand.samples) == len(kept.samples) - np.sum(
        kept.samples.link == kept.link_index("forearm")
    )


@pytest.mark.parametrize(
    ("top", "message"),
    [
        ('excluded_links = ["elbow"]', "excluded link 'elbow' is not a link"),
        ('excluded_links = ["t_1"]', "fingertip link 't_1' is also in excluded_links"),
        ("outer_surface_only = 1", "outer_surface_only must be true or false"),
    ],
)
def test_bad_link_options_are_named(tmp_path, top, message):
    with pytest.raises(ConfigError, match=message):
        load_hand(write_toy_hand(tmp_path / "toy", top))


def test_outer_surface_only_drops_exactly_the_samples_inside_the_palm(tmp_path):
    """The knuckle box lies 5 mm or more inside the palm box (same link): every sample on it is
    buried, and no other sample is."""
    size, centre = np.array(KNUCKLE[0]), np.array(KNUCKLE[1])
    both = load_hand(write_toy_hand(tmp_path / "a", knuckle=True))
    p = both.samples.p_joint[both.samples.link == both.link_index("palm")]  # palm frame = base
    on_knuckle = np.all(np.abs(p - centre) <= 0.5 * size + 1e-9, axis=1)
    assert 10 < on_knuckle.sum() < len(p)
    outer = load_hand(write_toy_hand(tmp_path / "b", "outer_surface_only = true", knuckle=True))
    assert len(outer.samples) == len(both.samples) - on_knuckle.sum()
    kept = outer.samples.p_joint[outer.samples.link == outer.link_index("palm")]
    np.testing.assert_array_equal(kept, p[~on_knuckle])
    # Links that only touch the palm (the finger bases on its top edge) keep every sample.
    for link in ("f1_1", "t_1"):
        assert np.sum(outer.samples.link == outer.link_index(link)) == np.sum(
            both.samples.link == both.link_index(link)
        )


def test_a_root_link_named_world_keeps_its_placement_in_mujoco(tmp_path):
    """MuJoCo's URDF importer takes a link named ``world`` for its world body; the hand's root
    turn (90 deg here) must survive: every link body where Pinocchio puts it."""
    folder = write_toy_hand(tmp_path / "toy", palm_xyz=(0.0, 0.0, 0.05), palm_rpy=(1.5708, 0, 0))
    urdf = folder / "toy.urdf"
    urdf.write_text(urdf.read_text().replace('"root"', '"world"'))
    hand = load_hand(folder)
    backend = MujocoBackend(hand, ObjectModel.sphere(0.03, mass=0.1))
    q = hand.neutral()
    backend.set_kinematic_hand(q)
    kin_data = hand.model.createData()
    pin.framesForwardKinematics(hand.model, kin_data, q)
    for i, frame in enumerate(hand.link_frame):
        wMl = hand.wMb @ kin_data.oMf[int(frame)].homogeneous
        body = backend.scene.link_body[i]
        np.testing.assert_allclose(backend.data.xpos[body], wMl[:3, 3], atol=1e-9)
        np.testing.assert_allclose(backend.data.xmat[body].reshape(3, 3), wMl[:3, :3], atol=1e-9)


def _control(folder, table: str):
    path = folder / "hand.toml"
    path.write_text(path.read_text().replace("[grasping]", f"[control]\n{table}\n\n[grasping]"))
    return folder


def test_a_hands_squeeze_is_every_allocators_minimum_unless_the_user_sets_one(tmp_path):
    """``[control] squeeze`` reaches the allocators as their ``f_n_min`` (the QP then keeps
    that much normal force in all); an allocator parameter given by the user wins."""
    from wholehand.contacts.base import ContactSet
    from wholehand.trials.trial import load_allocator

    plain = load_hand(write_toy_hand(tmp_path / "plain"))
    assert load_allocator("qp", plain, {}).params.f_n_min == 10.0  # the paper's
    hand = load_hand(_control(write_toy_hand(tmp_path / "toy"), "squeeze = 25.0"))
    assert hand.config.squeeze == 25.0
    qp = load_allocator("qp", hand, {})
    assert qp.params.f_n_min == 25.0
    assert load_allocator("qp", hand, {"f_n_min": 5.0}).params.f_n_min == 5.0
    # Two opposed contacts on the x axis, each free to push along its inward normal.
    J = np.zeros((2, 3, qp.params.tau_max.size))
    J[0, 0, 0], J[1, 0, 1] = 0.01, -0.01  # 1 cm levers: 0.125 N*m each
    contacts = ContactSet(
        p_world=np.array([[-0.02, 0.0, 0.0], [0.02, 0.0, 0.0]]),
        n_world=np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]),
        link=np.array([0, 1]),
        distance=np.zeros(2),
        link_actuated=np.ones(2, dtype=bool),
        link_fingertip=np.ones(2, dtype=bool),
    )
    allocation = qp.allocate(contacts, J, np.zeros(3))
    assert allocation.ok
    normal = np.einsum("ij,ij->i", allocation.f_world, -contacts.n_world)  # pressing in
    np.testing.assert_allclose(normal, [12.5, 12.5], atol=1e-4)


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ("squeeze = -1.0", r"\[control\] squeeze \(the minimum squeeze \[N\]\) must be >= 0"),
        ('squeeze = "hard"', "must be a number"),
        ("grip = 3.0", r"unknown keys \['grip'\] in \[control\]; valid keys are \['squeeze'\]"),
    ],
)
def test_bad_control_options_are_named(tmp_path, table, message):
    with pytest.raises(ConfigError, match=message):
        load_hand(_control(write_toy_hand(tmp_path / "toy"), table))
