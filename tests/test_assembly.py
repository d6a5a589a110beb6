"""Arm-hand assemblies by config: the merged model against the arm and the hand loaded apart,
gravity torques against finite differences of the potential energy, a gravity-compensated arm
holding still in MuJoCo, the Rizon 4 build, and bad [assembly] tables."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from wholehand import registry
from wholehand.backends.command import Command, JointTargets
from wholehand.errors import AssetError, ConfigError
from wholehand.models.gravity import GravityCompensation
from wholehand.models.hand import load_hand
from wholehand.models.hand_folders import shipped_hands_dir
from wholehand.models.objects import ObjectModel

ROBOTS = shipped_hands_dir()
ARM_URDF = ROBOTS / "flexiv_rizon4" / "rizon4.urdf"
UPSTREAM = Path(__file__).resolve().parents[2] / "shared/assets/flexiv_rizon4/flexiv_description"


@pytest.fixture(scope="module")
def rig():
    return load_hand("flexiv_rizon4_allegro_right")


def test_assembly_is_the_arm_plus_the_hand(rig, allegro) -> None:
    assert rig.nq == 7 + allegro.nq
    assert int(rig.arm_dofs.sum()) == 7 and not (rig.arm_dofs & rig.actuated_dofs).any()
    np.testing.assert_array_equal(rig.tau_max[rig.arm_dofs], [123, 123, 64, 64, 39, 39, 39])
    assert sorted(rig.link_names) == sorted(allegro.link_names)  # arm links: no contact samples
    assert int(rig.actuated_dofs.sum()) == int(allegro.actuated_dofs.sum())
    assert rig.config.hand_toml == allegro.config.path
    assert rig.palm_link == allegro.palm_link and rig.config.fingers == allegro.config.fingers
    assert rig.config.arm_home == (0.0, -0.69813, 0.0, 1.570796, 0.0, 0.69813, 0.0)


def test_hand_links_sit_on_the_flange_as_mounted(rig, allegro) -> None:
    # Ground truth from the arm and the hand loaded apart: palm = flange * mount * (hand FK).
    arm = pin.buildModelFromUrdf(str(ARM_URDF))
    arm_data = arm.createData()
    rng = np.random.default_rng(0)
    for _ in range(3):
        q_arm = rng.uniform(arm.lowerPositionLimit, arm.upperPositionLimit)
        q_hand = rng.uniform(allegro.q_lower, allegro.q_upper)
        pin.framesForwardKinematics(arm, arm_data, q_arm)
        flange = arm_data.oMf[arm.getFrameId("flange")].homogeneous
        mount = np.eye(4)
        mount[2, 3] = 0.095
        hand_data = allegro.model.createData()
        pin.framesForwardKinematics(allegro.model, hand_data, q_hand)
        q = np.zeros(rig.nq)
        for name, value in zip(arm.names[1:], q_arm, strict=True):
            q[rig.model.joints[rig.model.getJointId(name)].idx_q] = value
        for name in allegro.joint_names:
            q_i = allegro.model.joints[allegro.model.getJointId(name)].idx_q
            q[rig.model.joints[rig.model.getJointId(name)].idx_q] = q_hand[q_i]
        rig_data = rig.model.createData()
        pin.framesForwardKinematics(rig.model, rig_data, q)
        for link in ("link_3.0_tip", "link_15.0_tip", allegro.palm_link):
            expected = flange @ mount @ hand_data.oMf[allegro.model.getFrameId(link)].homogeneous
            got = rig_data.oMf[rig.model.getFrameId(link)].homogeneous
            np.testing.assert_allclose(got, expected, atol=1e-12)


def test_gravity_torques_are_the_gradient_of_the_potential_energy(rig) -> None:
    comp = GravityCompensation(rig)
    rng = np.random.default_rng(1)
    q = rng.uniform(rig.q_lower, rig.q_upper)
    wMb = np.eye(4)
    wMb[:3, :3] = pin.exp3(np.array([0.3, -0.2, 0.5]))  # gravity turns with the base
    model = pin.Model(rig.model)
    model.gravity.linear = wMb[:3, :3].T @ np.array([0.0, 0.0, -9.81])
    data = model.createData()

    def energy(x: np.ndarray) -> float:
        return float(pin.computePotentialEnergy(model, data, x))

    h = 1e-6
    fd = np.array([(energy(q + h * e) - energy(q - h * e)) / (2 * h) for e in np.eye(rig.nq)])
    np.testing.assert_allclose(comp.torques(q, wMb), fd, atol=1e-5)


def test_a_gravity_compensated_arm_holds_still_and_an_uncompensated_one_sags(rig) -> None:
    q0 = rig.neutral().copy()
    arm = np.flatnonzero(rig.arm_dofs)
    q0[arm] = [0.0, -0.7, 0.0, 1.57, 0.0, 0.7, 0.0]
    far = np.eye(4)
    far[:3, 3] = [2.0, 2.0, 0.1]
    obj = ObjectModel.box((0.05, 0.05, 0.05))
    backend = registry.load(
        "backends", "mujoco", hand=rig, obj=obj, q_init=q0, wMo_init=far, gravity=True
    )
    comp = GravityCompensation(rig)
    kp, kd = rig.config.arm_gains
    drift = {}
    for feedforward in (True, False):
        backend.reset(q0, far)
        for _ in range(200):
            obs = backend.observe()
            tau = np.zeros(rig.nv)
            if feedforward:
                tau[arm] = comp.torques(obs.q, obs.wMb)[arm]
            servo = JointTargets(arm, q0[arm], None, kp, kd, name="arm")
            backend.apply(Command(tau, (servo,)))
            backend.step(0.005)
        drift[feedforward] = np.abs(backend.observe().q[arm] - q0[arm])
    assert drift[True].max() < 1e-3
    assert drift[False][1] > 0.1  # the shoulder sags under the arm's own weight
    assert not any(backend.warnings().values())


def _wrist_speed_while_holding_still(rig, armature: float) -> float:
    """Largest speed [rad/s] of the last arm joint over the second 0.5 s of holding the home
    posture with the fingers pressing on a box fixed in the palm's way, ``armature`` on the arm
    joints of the compiled model."""
    q0 = rig.neutral().copy()
    arm = np.flatnonzero(rig.arm_dofs)
    q0[arm] = rig.config.arm_home
    far = np.eye(4)
    far[:3, 3] = [2.0, 2.0, 0.1]
    backend = registry.load(
        "backends",
        "mujoco",
        hand=rig,
        obj=ObjectModel.box((0.05, 0.05, 0.05)),
        q_init=q0,
        wMo_init=far,
        gravity=True,
    )
    model = backend.model
    for name in rig.config.arm_joints:
        model.dof_armature[model.joint(name).dofadr[0]] = armature
    comp = GravityCompensation(rig)
    kp, kd = rig.config.arm_gains
    hand = np.flatnonzero(rig.actuated_dofs)
    wrist = arm[-1]
    speeds = []
    for k in range(200):
        obs = backend.observe()
        tau = np.zeros(rig.nv)
        tau[arm] = comp.torques(obs.q, obs.wMb)[arm]
        tau[hand] = 0.1  # fingers closing hard into a fist: reactions on the wrist
        backend.apply(Command(tau, (JointTargets(arm, q0[arm], None, kp, kd, name="arm"),)))
        backend.step(0.005)
        if k >= 100:
            speeds.append(abs(backend.observe().dq[wrist]))
    return float(max(speeds))


def test_arm_armature_keeps_the_servo_damping_stable_on_the_light_wrist_joint(rig) -> None:
    # The Rizon 4's last joint with a hand has ~0.004 kg*m^2 about its axis: with kd = 20 the
    # explicit damping overshoots each 1 ms step (kd dt / I = 4.4) and the wrist shakes.
    model_armature = 0.001  # the hand's [simulation] armature, which the arm joints had before
    assert _wrist_speed_while_holding_still(rig, model_armature) > 1.0
    assert _wrist_speed_while_holding_still(rig, rig.config.arm_armature) < 0.05


def test_scene_gives_arm_joints_the_arm_armature_and_hand_joints_their_own(rig) -> None:
    backend = registry.load("backends", "mujoco", hand=rig, obj=ObjectModel.sphere(0.03))
    model = backend.model
    for name in rig.config.arm_joints:
        assert model.dof_armature[model.joint(name).dofadr[0]] == 0.1
    for name in rig.joint_names:
        if name not in rig.config.arm_joints:
            assert model.dof_armature[model.joint(name).dofadr[0]] == rig.config.armature


def test_backend_refuses_an_arm_servo_that_overshoots_and_names_the_fix(tmp_path) -> None:
    folder = write_assembly(tmp_path / "rig", GOOD + "\narm_armature = 0.001")
    rig = load_hand(folder)
    assert rig.config.arm_armature == 0.001
    with pytest.raises(ConfigError, match=r"kd \* dt / armature = 20.00 > 1.*at least 0.02"):
        registry.load("backends", "mujoco", hand=rig, obj=ObjectModel.sphere(0.03))


def test_rizon4_build_reproduces_the_shipped_urdf(tmp_path: Path) -> None:
    pytest.importorskip("xacro")
    if not UPSTREAM.is_dir():
        pytest.skip(f"upstream files not at {UPSTREAM}")
    from importlib import util

    spec = util.spec_from_file_location("build", ROBOTS / "flexiv_rizon4" / "build_urdf.py")
    assert spec is not None and spec.loader is not None
    build = util.module_from_spec(spec)
    spec.loader.exec_module(build)
    out = build.build(UPSTREAM, tmp_path)
    assert out.read_text() == ARM_URDF.read_text()
    for stl in (ROBOTS / "flexiv_rizon4" / "meshes").glob("*.stl"):
        assert (tmp_path / "meshes" / stl.name).read_bytes() == stl.read_bytes()


def write_assembly(folder: Path, assembly: str, extra: str = "") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copytree(ROBOTS / "flexiv_rizon4", folder / "arm", dirs_exist_ok=True)
    (folder / "hand.toml").write_text(f'name = "rig"\n{extra}\n[assembly]\n{assembly}\n')
    return folder


GOOD = 'arm = "arm/rizon4.urdf"\nhand = "allegro_right"\nflange = "flange"'


@pytest.mark.parametrize(
    ("assembly", "extra", "error", "message"),
    [
        ('arm = "arm/rizon4.urdf"\nhand = "allegro_right"', "", ConfigError, "lacks .'flange'."),
        (GOOD + "\ncolour = 1", "", ConfigError, "unknown keys .'colour'."),
        (GOOD.replace('"flange"', '"wrist"'), "", ConfigError, "flange 'wrist' is not a link"),
        (GOOD.replace("arm/rizon4", "arm/none"), "", AssetError, "arm URDF .* does not exist"),
        (GOOD.replace("allegro_right", "no_hand"), "", ConfigError, "no hand named 'no_hand'"),
        (GOOD, 'palm_link = "palm"', ConfigError, "belong in the hand's hand.toml"),
        (GOOD + "\narm_gains = { kp = -1 }", "", ConfigError, "arm_gains.kp must be > 0"),
        (
            GOOD + '\nmount = { xyz = "up" }',
            "",
            ConfigError,
            "mount.xyz must be a list of 3 finite",
        ),
        (GOOD + "\nhome = [0.0, 1.0]", "", ConfigError, "home has 2 angles; the arm has 7"),
        (GOOD + '\nhome = ["up"]', "", ConfigError, "home must be a list of angles"),
        (GOOD + "\narm_armature = 0", "", ConfigError, "arm_armature must be a rotor inertia"),
        (GOOD + "\narm_armature = true", "", ConfigError, "arm_armature must be a rotor"),
    ],
)
def test_bad_assembly_tables_are_named(tmp_path, assembly, extra, error, message) -> None:
    folder = write_assembly(tmp_path / "rig", assembly, extra)
    with pytest.raises(error, match=message):
        load_hand(folder)


def test_an_arm_reaches_grasps_loses_and_regrasps() -> None:
    from wholehand.reaching.episode import run_episode
    from wholehand.reaching.episode_spec import EpisodeSpec

    summary = run_episode(EpisodeSpec(hand="flexiv_rizon4_allegro_right", seed=0), record=True)
    record = summary.pop("record")
    stages = [(t["source"], t["target"]) for t in summary["transitions"]]
    assert stages[0] == ("reach_pregrasp", "reach_grasp") and ("reach_grasp", "regulate") in stages
    assert summary["mount"] == "arm"
    assert summary["losses"] >= 1 and summary["recovered"] >= 1 and summary["complete"]
    assert summary["loop"]["n_errors"] == 0 and not any(summary["mujoco_warnings"].values())
    # The base never moves (the arm's root is fixed); the arm's joints carry the hand.
    base = np.asarray(record.rows["p_base"])
    np.testing.assert_allclose(base, base[:1].repeat(len(base), axis=0))
    q = np.asarray(record.rows["q"])
    rig = load_hand("flexiv_rizon4_allegro_right")
    assert np.abs(q[:, rig.arm_dofs] - q[0, rig.arm_dofs]).max() > 0.1
