"""Hands described in MJCF: the same toy hand as URDF and MJCF gives the same model and scene."""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from toy_hand import MIMIC, write_toy_hand
from wholehand_plugins.mujoco.backend import MujocoBackend

from wholehand.backends.command import Command
from wholehand.models.coupling import Mimic
from wholehand.models.hand import load_hand
from wholehand.models.objects import ObjectModel

PALM = {"palm_xyz": (0.01, 0.02, 0.03), "palm_rpy": (0.3, -0.5, 1.2)}
MOUNT = "[mount]\nxyz = [0.1, -0.2, 0.3]\nrpy = [0.2, 0.1, -0.4]\n"


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    root = tmp_path_factory.mktemp("hands")
    urdf = load_hand(write_toy_hand(root / "urdf", tables=MOUNT, mimic=True, **PALM))
    mjcf = load_hand(write_toy_hand(root / "mjcf", tables=MOUNT, mjcf=True, mimic=True, **PALM))
    return urdf, mjcf


def test_the_mjcf_hand_has_the_urdf_hands_links_joints_and_couplings(pair):
    urdf, mjcf = pair
    assert mjcf.config.model_format == "mjcf"
    assert mjcf.joint_names == urdf.joint_names
    assert mjcf.link_names == urdf.link_names  # the visual-only sphere is no contact link
    np.testing.assert_array_equal(mjcf.q_lower, urdf.q_lower)
    assert (
        mjcf.mimics
        == urdf.mimics
        == {
            "f1_j2": Mimic("f1_j1", *MIMIC),
            "f2_j2": Mimic("f2_j1", *MIMIC),
        }
    )
    np.testing.assert_array_equal(mjcf.coupling, urdf.coupling)
    rng = np.random.default_rng(0)
    for _ in range(3):
        q = mjcf.couple(rng.uniform(mjcf.q_lower, mjcf.q_upper))
        poses = []  # relative to the palm: Pinocchio takes an MJCF's root body as the base
        for hand in pair:
            data = hand.model.createData()
            pin.framesForwardKinematics(hand.model, data, q)
            oMpalm = data.oMf[hand.model.getFrameId("palm")]
            poses.append(
                [
                    (oMpalm.inverse() * data.oMf[hand.model.getFrameId(n)]).homogeneous
                    for n in hand.link_names
                ]
            )
        np.testing.assert_allclose(poses[0], poses[1], atol=1e-12)
    assert len(mjcf.samples) == len(urdf.samples)


def test_the_mjcf_scene_is_mounted_and_keeps_only_what_the_controller_drives(pair):
    urdf, mjcf = pair
    backend = MujocoBackend(mjcf, ObjectModel.sphere(0.01, mass=0.01))
    model = backend.model
    assert model.nu == 3  # motors on f1_j1, f2_j1, t_j1; the file's position actuators gone
    assert all(model.actuator(i).name.startswith("motor_") for i in range(model.nu))
    assert model.nkey == 0 and model.neq == 2
    assert "floor" not in [model.geom(g).name for g in range(model.ngeom)]
    assert "palm_visual" not in [model.geom(g).name for g in range(model.ngeom)]
    np.testing.assert_allclose(backend.observe().wMb, mjcf.wMb, atol=1e-12)
    q = mjcf.couple(np.array([0.3, 0.0, 0.6, 0.0, 0.4]))
    backend.set_kinematic_hand(q)
    data = mjcf.model.createData()
    pin.framesForwardKinematics(mjcf.model, data, q)
    for i, frame in enumerate(mjcf.link_frame):
        wMl = mjcf.wMb @ data.oMf[int(frame)].homogeneous
        body = backend.scene.link_body[i]
        np.testing.assert_allclose(backend.data.xpos[body], wMl[:3, 3], atol=1e-9)
        np.testing.assert_allclose(backend.data.xmat[body].reshape(3, 3), wMl[:3, :3], atol=1e-9)
    # One actuator torque closes both joints of finger 1 along the coupling.
    backend.apply(Command.torques(mjcf.joint_torques(np.array([0.05, 0.0, 0.0]))))
    backend.step(0.3)
    q_now = backend.observe().q
    assert q_now[0] > q[0] + 0.05
    assert q_now[1] == pytest.approx(MIMIC[0] * q_now[0] + MIMIC[1], abs=2e-3)
    assert model.eq_type[0] == mujoco.mjtEq.mjEQ_JOINT


def test_an_mjcf_equality_that_fixes_a_joint_is_named(tmp_path):
    from wholehand.errors import ConfigError

    folder = write_toy_hand(tmp_path / "toy", mjcf=True)
    xml = folder / "toy.xml"
    fixed = '<equality><joint joint1="t_j1"/></equality>'
    xml.write_text(xml.read_text().replace("<equality></equality>", fixed))
    with pytest.raises(ConfigError, match="holds joint 't_j1' fixed; lock it in hand.toml"):
        load_hand(folder)


def test_hand_check_reads_an_mjcf_hand(tmp_path, capsys):
    from wholehand.cli.main import main

    folder = write_toy_hand(tmp_path / "toy", mjcf=True, mimic=True)
    assert main(["hand", "check", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "f1_j2" in out and "follows f1_j1" in out and "NOT usable" not in out
    xml = folder / "toy.xml"
    limited = 'name="t_j1" axis="0 -1 0" range="-0.2 1.6"'
    xml.write_text(xml.read_text().replace(limited, 'name="t_j1" axis="0 -1 0" limited="false"'))
    assert main(["hand", "check", str(folder)]) == 1
    assert "joints without a range in toy.xml: ['t_j1']" in capsys.readouterr().out


@pytest.mark.parametrize("base", ["mocap", "floating"])
def test_an_mjcf_hand_on_a_moving_base_follows_it(pair, base):
    """The base of an MJCF hand moved by ``Command.base``: kinematically (``mocap``) or through
    the soft weld of a free base (``floating``); the links stay where Pinocchio puts them."""
    _, mjcf = pair
    backend = MujocoBackend(mjcf, ObjectModel.sphere(0.01, mass=0.01), base=base)
    assert backend.model.nmocap == 1
    np.testing.assert_allclose(backend.observe().wMb, mjcf.wMb, atol=1e-9)
    moved = mjcf.wMb.copy()
    moved[:3, 3] += [0.05, -0.03, 0.02]
    moved[:3, :3] = moved[:3, :3] @ pin.rpy.rpyToMatrix(0.0, 0.0, 0.3)
    q = mjcf.couple(np.array([0.3, 0.0, 0.6, 0.0, 0.4]))
    backend.set_kinematic_hand(q)
    backend.apply(Command(np.zeros(mjcf.nv), base=moved))
    backend.step(0.5)
    obs = backend.observe()
    np.testing.assert_allclose(obs.wMb, moved, atol=1e-3)
    data = mjcf.model.createData()
    pin.framesForwardKinematics(mjcf.model, data, obs.q)
    for i, frame in enumerate(mjcf.link_frame):
        wMl = obs.wMb @ data.oMf[int(frame)].homogeneous
        np.testing.assert_allclose(
            backend.data.xpos[backend.scene.link_body[i]], wMl[:3, 3], atol=1e-6
        )
