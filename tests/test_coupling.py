"""Coupled (URDF <mimic>) joints: actuator coordinates, hand-computed torques, MuJoCo."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
from toy_hand import MIMIC, write_toy_hand
from wholehand_plugins.mujoco.backend import MujocoBackend

from wholehand.allocation.base import hand_keywords
from wholehand.backends.command import Command
from wholehand.errors import ConfigError
from wholehand.models.coupling import Mimic, resolve_chains
from wholehand.models.hand import load_hand
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel

M, OFFSET = MIMIC


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    return load_hand(write_toy_hand(tmp_path_factory.mktemp("hands") / "toy", mimic=True))


@pytest.fixture(scope="module")
def toml_toy(tmp_path_factory):
    """The toy hand with a URDF without <mimic> tags and the couplings in hand.toml."""
    folder = tmp_path_factory.mktemp("hands") / "toml_toy"
    return load_hand(write_toy_hand(folder, toml_coupling=True))


def test_hand_toml_couplings_are_the_urdf_mimic_tags(toy, toml_toy):
    assert "<mimic" not in toml_toy.config.model_path.read_text()
    assert toml_toy.mimics == toy.mimics
    np.testing.assert_array_equal(toml_toy.coupling, toy.coupling)
    np.testing.assert_array_equal(toml_toy.coupling_offset, toy.coupling_offset)
    np.testing.assert_array_equal(toml_toy.actuated_dofs, toy.actuated_dofs)
    scenes = [MujocoBackend(h, ObjectModel.sphere(0.01, mass=0.01)).model for h in (toy, toml_toy)]
    for model in scenes:
        assert model.neq == 2 and model.nu == 3
    # The same equalities as MuJoCo's URDF importer makes of the <mimic> tags: a0, a1.
    np.testing.assert_allclose(scenes[1].eq_data[:, :5], scenes[0].eq_data[:, :5], atol=1e-12)
    np.testing.assert_allclose(scenes[1].eq_data[:, :2], [[OFFSET, M], [OFFSET, M]])


@pytest.mark.parametrize(
    ("toml", "message"),
    [
        ('coupled = { f1_j2 = { leader = "nope" } }', "'nope' is not a moving joint"),
        ("coupled = { f1_j2 = { multiplier = 2.0 } }", "must name its leader joint"),
        ('coupled = { f1_j2 = { leader = "f1_j1", gain = 2 } }', "unknown keys \\['gain'\\]"),
        ('coupled = { f1_j2 = { leader = "f1_j1", multiplier = "x" } }', "must be a number"),
        ('coupled = { f1_j2 = { leader = "f1_j1", offset = nan } }', "must be finite"),
        ('coupled = ["f1_j2"]', "must be a table"),
    ],
)
def test_bad_hand_toml_couplings_are_named(tmp_path, toml, message):
    folder = write_toy_hand(tmp_path / "toy", tables=f"[joints]\n{toml}\n", coupled_close=True)
    with pytest.raises(ConfigError, match=message):
        load_hand(folder)


def test_a_coupling_cycle_declared_in_hand_toml_is_blamed_on_hand_toml(tmp_path):
    cycle = 'coupled = { f1_j2 = { leader = "f1_j1" }, f1_j1 = { leader = "f1_j2" } }'
    folder = write_toy_hand(tmp_path / "toy", tables=f"[joints]\n{cycle}\n", coupled_close=True)
    with pytest.raises(ConfigError) as err:
        load_hand(folder)
    message = str(err.value)
    assert "form a cycle" in message and "f1_j1: [joints] coupled in hand.toml" in message
    assert "<mimic>" not in message


def test_a_hand_toml_follower_named_as_a_motor_is_refused_with_its_declaration(tmp_path):
    tables = '[joints]\nactuated = ["f1_j2"]\ncoupled = { f1_j2 = { leader = "f1_j1" } }\n'
    folder = write_toy_hand(tmp_path / "toy", tables=tables, coupled_close=True)
    with pytest.raises(ConfigError, match="'f1_j2' follows 'f1_j1' \\(\\[joints\\] coupled\\)"):
        load_hand(folder)


def test_a_hand_toml_coupling_of_a_mimic_follower_is_refused(tmp_path):
    tables = '[joints]\ncoupled = { f1_j2 = { leader = "t_j1" } }\n'
    folder = write_toy_hand(tmp_path / "toy", tables=tables, mimic=True)
    with pytest.raises(ConfigError, match="'f1_j2' is already coupled in toy.urdf"):
        load_hand(folder)


def test_followers_have_no_motor_and_c_maps_actuators_to_joints(toy):
    assert toy.joint_names == ["f1_j1", "f1_j2", "f2_j1", "f2_j2", "t_j1"]
    assert toy.coupled and toy.n_actuation == 3
    assert toy.mimics == {"f1_j2": Mimic("f1_j1", M, OFFSET), "f2_j2": Mimic("f2_j1", M, OFFSET)}
    assert toy.actuated_dofs.tolist() == [True, False, True, False, True]
    C = [[1, 0, 0], [M, 0, 0], [0, 1, 0], [0, M, 0], [0, 0, 1]]
    np.testing.assert_array_equal(toy.coupling, C)
    np.testing.assert_array_equal(toy.coupling_offset, [0, OFFSET, 0, OFFSET, 0])
    assert toy.link_actuated.tolist() == [False, True, True, True, True, True]  # palm passive
    q = toy.neutral()
    assert q[1] == pytest.approx(M * q[0] + OFFSET) and q[3] == pytest.approx(M * q[2] + OFFSET)
    keywords = hand_keywords(toy)
    np.testing.assert_array_equal(keywords["tau_max"], [0.2, 0.2, 0.2])
    assert keywords["actuated_dofs"].tolist() == [True, True, True]
    np.testing.assert_array_equal(
        toy.joint_torques(np.array([0.1, -0.2, 0.3])), [0.1, 0, -0.2, 0, 0.3]
    )


def _ry(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def test_actuator_jacobian_is_the_hand_computed_one(toy):
    """A point on the tip of finger 1: d p / d q_act = y x (p - a1) + M y x (p - a2), with the
    joint axes a1 (finger base) and a2 (middle joint) placed by hand from the URDF numbers."""
    q1 = 0.3
    q = toy.couple(np.array([q1, 0.0, 0.5, 0.0, 0.2]))
    q2 = q[1]
    assert q2 == pytest.approx(M * q1 + OFFSET)
    a1 = np.array([0.0, 0.025, 0.0])
    a2 = a1 + _ry(q1) @ [0.0, 0.0, 0.04]
    p = a2 + _ry(q1 + q2) @ [0.0075, 0.0, 0.03]  # on the tip box's inner face
    y = np.array([0.0, 1.0, 0.0])
    expected = np.cross(y, p - a1) + M * np.cross(y, p - a2)
    kin = HandKinematics(toy)
    kin.update(q, np.eye(4))
    tip = toy.link_joint[toy.link_index("f1_2")]
    (J,) = kin.actuation_jacobians(np.array([tip]), p[None])
    np.testing.assert_allclose(J[:, 0], expected, atol=1e-12)
    np.testing.assert_allclose(J[:, 1:], 0.0, atol=1e-12)
    # The torque on actuator 1 for a force f at p is C^T J^T f (virtual work).
    f = np.array([-2.0, 0.5, 1.0])
    assert J.T @ f == pytest.approx([expected @ f, 0.0, 0.0])


@pytest.mark.parametrize("declared_in", ["toy", "toml_toy"])
def test_mujoco_keeps_the_coupling_and_c_transpose_balances_a_tip_force(request, declared_in):
    """A force F pushes the tip of finger 1; the actuator torque -(J C)^T F holds the finger
    still in MuJoCo (with the URDF <mimic>, or hand.toml's coupling, as a joint equality), while
    the torque that ignores the coupling (the leader's own Jacobian column only) lets it move."""
    toy = request.getfixturevalue(declared_in)
    q = toy.couple(np.array([0.3, 0.0, 0.3, 0.0, 0.2]))
    F = np.array([-1.5, 0.0, 0.5])  # on the finger, world = base frame
    drift = {}
    for law in ("coupled", "leader_only"):
        backend = MujocoBackend(toy, ObjectModel.sphere(0.01, mass=0.01))  # far from the hand
        assert backend.model.neq == 2
        backend.set_kinematic_hand(q)
        kin = HandKinematics(toy)
        kin.update(q, backend.observe().wMb)
        body = backend.scene.link_body[toy.link_index("f1_2")]
        p = backend.data.xpos[body] + backend.data.xmat[body].reshape(3, 3) @ [0.0075, 0, 0.03]
        joint = np.array([toy.link_joint[toy.link_index("f1_2")]])
        if law == "coupled":
            tau_a = -(kin.actuation_jacobians(joint, p[None])[0].T @ F)
        else:
            tau_a = -(kin.point_jacobians(joint, p[None])[0].T @ F)[toy.actuated_dofs]
        backend.data.xfrc_applied[body, :3] = F
        backend.data.xfrc_applied[body, 3:] = np.cross(p - backend.data.xipos[body], F)
        backend.apply(Command.torques(toy.joint_torques(tau_a)))
        backend.step(0.3)
        q_now = backend.observe().q
        assert q_now[1] == pytest.approx(M * q_now[0] + OFFSET, abs=2e-3)  # the equality holds
        drift[law] = float(np.abs(q_now[:2] - q[:2]).max())
    assert drift["coupled"] < 2e-3 < 0.05 < drift["leader_only"]


def test_chains_resolve_to_the_first_leader_and_bad_tags_are_named():
    mimics = {"j3": Mimic("j2", 2.0, 0.5), "j2": Mimic("j1", 3.0, 0.1)}
    resolved = resolve_chains(mimics, ["j1", "j2", "j3"], Path("h.urdf"))
    assert resolved["j3"] == Mimic("j1", 6.0, 2.0 * 0.1 + 0.5)
    with pytest.raises(ConfigError, match="'j9' is not a moving joint"):
        resolve_chains({"j2": Mimic("j9", 1.0, 0.0)}, ["j1", "j2"], Path("h.urdf"))
    with pytest.raises(ConfigError, match="form a cycle"):
        resolve_chains(
            {"j1": Mimic("j2", 1.0, 0.0), "j2": Mimic("j1", 1.0, 0.0)}, ["j1", "j2"], Path("h")
        )


def test_a_follower_named_as_a_motor_is_refused(tmp_path):
    folder = write_toy_hand(tmp_path / "toy", mimic=True)
    toml = folder / "hand.toml"
    toml.write_text(
        toml.read_text().replace("[grasping]", '[joints]\nactuated = ["f1_j2"]\n\n[grasping]')
    )
    with pytest.raises(ConfigError, match="'f1_j2' follows 'f1_j1' \\(URDF <mimic>\\)"):
        load_hand(folder)


PANDA = """
name = "panda_gripper"
urdf = { distribution = "example-robot-data", path = "robots/panda_description/urdf/panda.urdf" }
palm_link = "panda_hand"
fingertip_links = ["panda_leftfinger", "panda_rightfinger"]
excluded_links = ["panda_link0", "panda_link1", "panda_link2", "panda_link3", "panda_link4",
                  "panda_link5", "panda_link6", "panda_link7"]
[fingers]
left = ["panda_leftfinger"]
right = ["panda_rightfinger"]
[joints]
torque_limit = { default = 20.0 }
[joints.locked]
panda_joint1 = 0.0
panda_joint2 = 0.0
panda_joint3 = 0.0
panda_joint4 = -1.5
panda_joint5 = 0.0
panda_joint6 = 1.5
panda_joint7 = 0.8
"""


def test_a_real_gripper_with_a_mimic_joint_on_a_locked_arm(tmp_path):
    """Franka's gripper (example-robot-data): finger 2 mimics finger 1; the arm is locked and
    its links excluded. One actuator force closes both fingers by the same amount in MuJoCo."""
    folder = tmp_path / "panda"
    folder.mkdir()
    (folder / "hand.toml").write_text(PANDA)
    hand = load_hand(folder)
    assert hand.joint_names == ["panda_finger_joint1", "panda_finger_joint2"]
    assert hand.mimics == {"panda_finger_joint2": Mimic("panda_finger_joint1", 1.0, 0.0)}
    np.testing.assert_array_equal(hand.coupling, [[1.0], [1.0]])
    assert hand.link_names == ["panda_hand", "panda_leftfinger", "panda_rightfinger"]
    backend = MujocoBackend(hand, ObjectModel.sphere(0.01, mass=0.01))
    eq = backend.model.eq_type == mujoco.mjtEq.mjEQ_JOINT
    assert eq.sum() == 1
    backend.set_kinematic_hand(np.array([0.03, 0.03]))
    backend.apply(Command.torques(hand.joint_torques(np.array([-0.5]))))  # close
    backend.step(0.02)
    q = backend.observe().q
    assert 0.0 < q[0] < 0.029 and q[0] == pytest.approx(q[1], abs=1e-4)
