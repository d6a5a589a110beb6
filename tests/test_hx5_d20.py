"""The ROBOTIS HX5-D20 right hand (the paper's 20-DoF hand): its files, model and simulation."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import trimesh
from wholehand_plugins.mujoco.backend import MujocoBackend

from wholehand.backends.command import Command
from wholehand.grasps.generate import generate_grasps
from wholehand.grasps.store import load_grasps
from wholehand.models.hand import load_hand
from wholehand.models.hand_folders import shipped_hands_dir
from wholehand.models.object_catalogue import PAPER_OBJECTS, load_object
from wholehand.models.objects import ObjectModel
from wholehand.models.poses import pose_from_xyz_rpy
from wholehand.trials.outcome import outcome_of
from wholehand.trials.trial import TrialSpec, run_trial

FOLDER = shipped_hands_dir() / "robotis_hx5_d20_right"
UPSTREAM = Path(__file__).resolve().parents[2] / "shared/assets/robotis_hx5_d20"


@pytest.fixture(scope="module")
def hx5():
    return load_hand("robotis_hx5_d20_right")


def test_folder_ships_licence_provenance_and_its_build_script():
    for name in ("LICENSE", "README.md", "build_urdf.py", "hand.toml", "hx5_d20_right.urdf"):
        assert (FOLDER / name).is_file(), name
    assert "Apache License" in (FOLDER / "LICENSE").read_text()
    readme = (FOLDER / "README.md").read_text()
    assert "d59e479fb797fc852938a63404449ab137139e13" in readme


def test_twenty_revolute_joints_four_per_finger_at_the_papers_limit(hx5):
    assert hx5.nq == hx5.nv == 20
    kinds = {hx5.model.joints[j].shortname() for j in range(1, hx5.model.njoints)}
    assert kinds <= {"JointModelRX", "JointModelRY", "JointModelRZ"}
    assert hx5.actuated_dofs.all()
    # The URDF says effort="1000" (a placeholder); hand.toml sets the paper's 0.2 N*m.
    efforts = {float(lim.get("effort")) for lim in ET.parse(hx5.config.model_path).iter("limit")}
    assert efforts == {1000.0}
    np.testing.assert_array_equal(hx5.tau_max, 0.2)
    fingers = hx5.config.fingers
    assert sorted(fingers) == ["index", "middle", "pinky", "ring", "thumb"]
    assert all(len(links) == 4 for links in fingers.values())
    assert len(hx5.link_names) == 21  # the base and 20 finger links; the tip markers have none
    assert not hx5.link_actuated[hx5.link_index(hx5.palm_link)]
    assert hx5.link_actuated.sum() == 20 and hx5.link_fingertip.sum() == 5


def test_samples_lie_on_the_upstream_meshes(hx5):
    for link in ("hx5_d20_right_base", "finger_r_link8", "finger_r_link4"):
        i = hx5.link_index(link)
        mesh = hx5.link_mesh(i)
        pts = hx5.samples.p_joint[hx5.samples.link == i]
        assert len(pts) >= 20
        # A sample lies on a face: in its plane, barycentric coordinates >= 0. (trimesh's
        # closest_point misplaces some points inside small triangles by ~0.2 mm, so it is not
        # the oracle here.)
        for p, faces in zip(pts, trimesh.proximity.nearby_faces(mesh, pts), strict=True):
            tri = mesh.triangles[faces]
            bary = trimesh.triangles.points_to_barycentric(tri, np.repeat(p[None], len(faces), 0))
            plane = np.abs(np.einsum("ij,ij->i", mesh.face_normals[faces], p - tri[:, 0]))
            assert np.any((bary.min(axis=1) >= -1e-6) & (plane < 1e-9)), (link, p)
    # Every link gets candidates, the palm (base unit) the most.
    counts = np.bincount(hx5.samples.link, minlength=len(hx5.link_names))
    assert counts.min() > 0 and counts.argmax() == hx5.link_index(hx5.palm_link)


def test_mujoco_kinematics_match_pinocchio(hx5):
    rng = np.random.default_rng(1)
    wMb = pose_from_xyz_rpy([0.1, -0.2, 0.3], [0.3, -0.4, 1.1])
    backend = MujocoBackend(hx5, ObjectModel.sphere(0.03, mass=0.1), wMb=wMb)
    data = hx5.model.createData()
    for _ in range(2):
        q = rng.uniform(hx5.q_lower, hx5.q_upper)
        backend.set_kinematic_hand(q)
        pin.framesForwardKinematics(hx5.model, data, q)
        for i, frame in enumerate(hx5.link_frame):
            wMl = wMb @ data.oMf[int(frame)].homogeneous
            body = backend.scene.link_body[i]
            np.testing.assert_allclose(backend.data.xpos[body], wMl[:3, 3], atol=1e-9)


@pytest.mark.parametrize("joint", ["finger_r_joint6", "finger_r_joint2"])
def test_a_joint_torque_moves_that_joint_its_way(hx5, joint):
    backend = MujocoBackend(hx5, ObjectModel.sphere(0.03, mass=0.1))
    i = hx5.joint_names.index(joint)
    q_mid = hx5.neutral()
    backend.set_kinematic_hand(q_mid)
    tau = np.zeros(hx5.nv)
    tau[i] = 0.1
    backend.apply(Command.torques(tau))
    q0 = backend.observe().q
    backend.step(0.01)
    dq = backend.observe().q - q0
    assert dq[i] > 0 and abs(dq[i]) > 5.0 * np.max(np.abs(np.delete(dq, i)))
    np.testing.assert_allclose(backend.applied_torques()[i], 0.1)


def test_the_build_script_reproduces_the_shipped_urdf(tmp_path):
    pytest.importorskip("xacro")  # a maintainer's tool, not a dependency
    if not UPSTREAM.is_dir():
        pytest.skip(f"upstream files not at {UPSTREAM}")
    import importlib.util

    spec = importlib.util.spec_from_file_location("build_urdf", FOLDER / "build_urdf.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    urdf = module.build(UPSTREAM / "robotis_hand_description", tmp_path)
    assert urdf.read_text() == (FOLDER / "hx5_d20_right.urdf").read_text()
    for mesh in (FOLDER / "meshes").iterdir():
        assert (tmp_path / "meshes" / mesh.name).read_bytes() == mesh.read_bytes()


@pytest.mark.parametrize("name", PAPER_OBJECTS)
def test_ten_power_grasps_ship_for_each_paper_object(hx5, name):
    grasps = load_grasps("robotis_hx5_d20_right", name)
    assert len(grasps) == 10
    for g in grasps:
        q = g.q_array(hx5)
        assert np.all(q >= hx5.q_lower - 0.01) and np.all(q <= hx5.q_upper + 0.01)
        assert "thumb" in g.extra["fingers"] and len(g.extra["fingers"]) >= 3


def test_generation_in_the_palm_frame_reproduces_the_shipped_grasps(hx5):
    """The HX5-D20's root is at its wrist, 12 cm below the knuckles: candidates are placed in
    the palm frame derived from the model, and the generator is deterministic."""
    cube = load_object("077_rubiks_cube")
    generated, info = generate_grasps(hx5, cube, count=2, seed=0)
    assert (
        info["candidates_tried"]
        == load_grasps("robotis_hx5_d20_right", "077_rubiks_cube")[1].extra["candidate"] + 1
    )
    for g, s in zip(
        generated, load_grasps("robotis_hx5_d20_right", "077_rubiks_cube"), strict=False
    ):
        np.testing.assert_allclose(g.oMb, s.oMb, atol=1e-8)
        assert g.q == pytest.approx(s.q, abs=1e-8)


def test_the_paper_hand_holds_a_grasp_through_the_load_test():
    spec = TrialSpec(
        hand="robotis_hx5_d20_right",
        object="065-f_cups",
        theta_deg=0.0,
        protocol_params={"settle_time": 0.2, "load_duration": 0.2},
    )
    record = run_trial(spec)
    outcome = outcome_of(record)
    assert outcome.held and outcome.unbalanced_cycles == 0
    assert record.meta["loop"]["faults"] == {}
