"""The MuJoCo backend: scene building, index maps, torques, poses, contacts, cavities, errors."""

from __future__ import annotations

import copy
import dataclasses
import math
import warnings

import mujoco
import numpy as np
import pinocchio as pin
import pytest
import trimesh
from wholehand_plugins.mujoco.backend import MujocoBackend
from wholehand_plugins.mujoco.scene import build_scene
from wholehand_plugins.mujoco.scene_options import HAND_BIT, OBJECT_BIT, SceneOptions

from wholehand.backends.command import Command
from wholehand.errors import AssetError, ConfigError, WholehandError
from wholehand.grasps.store import objects_with_grasps
from wholehand.models.convex import convex_decomposition, shipped_decomposition_file
from wholehand.models.object_catalogue import PAPER_OBJECTS, load_object
from wholehand.models.objects import ObjectModel
from wholehand.models.poses import pose_from_xyz_rpy


# --- objects ------------------------------------------------------------------------------------
def make_box(size=(0.05, 0.05, 0.05), mass=0.1):
    return ObjectModel.box(tuple(size), mass=mass)


def make_sphere(radius=0.03, mass=0.1):
    return ObjectModel.sphere(radius, mass=mass)


def make_ycb(name):
    return load_object(name)


# --- helpers ------------------------------------------------------------------------------------
PALM_UP = pose_from_xyz_rpy([0.0, 0.0, 0.0], [0.0, -math.pi / 2, 0.0])
"""Hand base pose with the palm's inner face (+x of palm_link) pointing up (+z world)."""
PALM_FACE_X = 0.0408 / 2 - 0.0093
"""x of the inner face of the Allegro palm's collision box in palm_link [m] (from the URDF)."""


def pose_in_front_of_palm(obj, wMb, gap=0.002):
    """Object pose that puts its bounding box `gap` in front of the palm face, fingers' side."""
    lo, hi = obj.mesh.bounds
    target_b = np.array([PALM_FACE_X + 0.5 * (hi - lo)[0] + gap, 0.0, -0.045])
    bMo = np.eye(4)
    bMo[:3, 3] = target_b - 0.5 * (lo + hi)
    return wMb @ bMo


def squeeze(hand, value=0.1):
    """(n_v,) torques flexing every finger joint (not the abduction joints) by `value` [N*m]."""
    tau = np.zeros(hand.nv)
    for i, name in enumerate(hand.joint_names):
        if name not in ("joint_0.0", "joint_4.0", "joint_8.0"):
            tau[i] = value
    return tau


def assert_no_warnings(backend):
    counts = backend.warnings()
    assert not any(counts.values()), counts


# --- scene --------------------------------------------------------------------------------------
@pytest.mark.parametrize("make", [make_sphere, make_box], ids=["sphere", "box"])
def test_primitive_scene_compiles_and_steps_cleanly(allegro, make):
    obj = make()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # MuJoCo compiler warnings become errors
        backend = MujocoBackend(
            allegro,
            obj,
            wMo_init=pose_in_front_of_palm(obj, PALM_UP),
            q_init=np.zeros(16),
            wMb=PALM_UP,
            gravity=True,
        )
    m = backend.model
    assert m.nu == int(allegro.actuated_dofs.sum())
    assert m.opt.timestep == pytest.approx(1e-3)
    assert m.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    body = backend.scene.object_body
    assert mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, body) == "object"
    assert m.body_mass[body] == pytest.approx(obj.mass)
    np.testing.assert_allclose(m.body_ipos[body], obj.com, atol=1e-12)
    # principal moments of the object's inertia, set explicitly (not from the geoms)
    np.testing.assert_allclose(
        np.sort(m.body_inertia[body]), np.linalg.eigvalsh(obj.inertia), rtol=1e-6
    )
    np.testing.assert_allclose(m.dof_damping[backend.scene.qvel_index], allegro.config.damping)
    np.testing.assert_allclose(m.dof_armature[backend.scene.qvel_index], allegro.config.armature)
    assert np.all(m.dof_frictionloss[backend.scene.qvel_index] == 0.0)
    backend.apply(Command.torques(squeeze(allegro)))
    backend.step(0.3)
    assert_no_warnings(backend)
    assert np.all(np.isfinite(backend.data.qpos))


@pytest.mark.parametrize(
    ("spec", "geom_type", "size"),
    [
        ("box:0.04x0.06x0.08", mujoco.mjtGeom.mjGEOM_BOX, [0.02, 0.03, 0.04]),
        ("sphere:0.035", mujoco.mjtGeom.mjGEOM_SPHERE, [0.035, 0.0, 0.0]),
        ("cylinder:0.03x0.12", mujoco.mjtGeom.mjGEOM_CYLINDER, [0.03, 0.06, 0.0]),
        ("capsule:0.02x0.08", mujoco.mjtGeom.mjGEOM_CAPSULE, [0.02, 0.04, 0.0]),
    ],
)
def test_primitive_geoms_have_exact_dimensions(allegro, spec, geom_type, size):
    obj = load_object(spec)
    scene = build_scene(allegro, obj)
    g = np.flatnonzero(scene.geom_is_object)
    assert g.size == 1 and scene.model.geom_type[g[0]] == geom_type
    np.testing.assert_allclose(scene.model.geom_size[g[0]], size, atol=1e-12)
    np.testing.assert_allclose(scene.model.geom_pos[g[0]], 0.0, atol=1e-12)
    np.testing.assert_allclose(scene.model.geom_quat[g[0]], [1.0, 0.0, 0.0, 0.0], atol=1e-12)
    # the ObjectModel's mesh is the same primitive: its bounds match MuJoCo's geom
    half = np.asarray(obj.mesh.extents) / 2
    radius, half_length = size[0], size[1]
    expected = {
        "box": size,
        "sphere": [radius] * 3,
        "cylinder": [radius, radius, half_length],
        "capsule": [radius, radius, half_length + radius],
    }[obj.kind]
    np.testing.assert_allclose(half, expected, atol=1e-3)


def test_visual_mesh_does_not_collide(allegro):
    obj = make_ycb("077_rubiks_cube")
    scene = build_scene(allegro, obj, options=SceneOptions(visual_mesh=True))
    g = mujoco.mj_name2id(scene.model, mujoco.mjtObj.mjOBJ_GEOM, "object_visual")
    assert g >= 0 and not scene.geom_is_object[g]
    assert scene.model.geom_contype[g] == 0 and scene.model.geom_conaffinity[g] == 0
    assert scene.model.mesh_facenum[scene.model.geom_dataid[g]] == len(obj.mesh.faces)


def test_friction_of_hand_object_contacts_is_the_objects(allegro):
    scene = build_scene(allegro, make_box(), options=SceneOptions(friction=0.3))
    m = scene.model
    obj_geoms = np.flatnonzero(scene.geom_is_object)
    hand_geoms = np.flatnonzero(scene.geom_link >= 0)
    # object geoms win the priority contest, so their friction is used as it is
    assert np.all(m.geom_priority[obj_geoms] > m.geom_priority[hand_geoms].max())
    np.testing.assert_allclose(m.geom_friction[obj_geoms, 0], 0.3)
    assert np.all(m.geom_contype[hand_geoms] == HAND_BIT)
    assert np.all(m.geom_contype[obj_geoms] == OBJECT_BIT)


@pytest.mark.parametrize("name", PAPER_OBJECTS)
def test_ycb_scene_compiles_and_steps_cleanly(allegro, name):
    obj = make_ycb(name)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        backend = MujocoBackend(
            allegro,
            obj,
            wMo_init=pose_in_front_of_palm(obj, PALM_UP),
            q_init=np.zeros(16),
            wMb=PALM_UP,
            gravity=True,
        )
    assert backend.scene.decomposition_parts > 1
    assert backend.data.ncon == 0  # placed clear of the hand
    backend.apply(Command.torques(squeeze(allegro)))
    backend.step(0.2)
    assert_no_warnings(backend)
    assert np.all(np.isfinite(backend.data.qpos))


# --- joint order --------------------------------------------------------------------------------
def test_joint_order_maps_by_name_fk_matches_pinocchio(allegro):
    rng = np.random.default_rng(0)
    wMb = pose_from_xyz_rpy([0.1, -0.2, 0.3], [0.3, -0.4, 1.1])
    backend = MujocoBackend(allegro, make_sphere(), wMb=wMb)
    scene = backend.scene
    names = [
        mujoco.mj_id2name(backend.model, mujoco.mjtObj.mjOBJ_JOINT, backend.model.dof_jntid[i])
        for i in scene.qvel_index
    ]
    assert names == list(allegro.joint_names)
    assert not np.array_equal(scene.qpos_index, np.arange(allegro.nq))  # the orders do differ
    data = allegro.model.createData()
    for _ in range(3):
        q = rng.uniform(allegro.q_lower, allegro.q_upper)
        backend.set_kinematic_hand(q)
        np.testing.assert_allclose(backend.observe().q, q, atol=0)
        pin.framesForwardKinematics(allegro.model, data, q)
        for i, frame in enumerate(allegro.link_frame):
            wMl = wMb @ data.oMf[int(frame)].homogeneous
            body = scene.link_body[i]
            np.testing.assert_allclose(backend.data.xpos[body], wMl[:3, 3], atol=1e-9)
            np.testing.assert_allclose(
                backend.data.xmat[body].reshape(3, 3), wMl[:3, :3], atol=1e-9
            )
    np.testing.assert_allclose(backend.observe().wMb, wMb, atol=1e-12)


def test_actuators_follow_pinocchio_order(allegro):
    backend = MujocoBackend(allegro, make_sphere())
    m = backend.model
    for i, aid in enumerate(backend.scene.ctrl_index):
        joint = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, m.actuator_trnid[aid, 0])
        assert joint == allegro.joint_names[i]
        np.testing.assert_allclose(
            m.actuator_ctrlrange[aid], [-allegro.tau_max[i], allegro.tau_max[i]]
        )
        np.testing.assert_allclose(m.actuator_forcerange[aid], m.actuator_ctrlrange[aid])


# --- torques ------------------------------------------------------------------------------------
def test_torques_are_clipped_to_limits(allegro):
    backend = MujocoBackend(allegro, make_sphere())
    signs = np.where(np.arange(allegro.nv) % 2 == 0, 1.0, -1.0)
    tau = 10.0 * allegro.tau_max * signs
    tau[3] = 0.05  # one inside the limits stays as it is
    backend.apply(Command.torques(tau))
    mujoco.mj_forward(backend.model, backend.data)
    expected = np.clip(tau, -allegro.tau_max, allegro.tau_max)
    np.testing.assert_allclose(backend.applied_torques(), expected)
    assert backend.applied_torques()[3] == pytest.approx(0.05)


@pytest.mark.parametrize("joint", ["joint_1.0", "joint_13.0", "joint_6.0"])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_joint_torque_accelerates_that_joint_its_way(allegro, joint, sign):
    backend = MujocoBackend(allegro, make_sphere())  # object far away, gravity off
    i = allegro.joint_names.index(joint)
    tau = np.zeros(allegro.nv)
    tau[i] = sign * 0.1
    backend.apply(Command.torques(tau))
    q0 = backend.observe().q
    backend.step(0.01)
    state = backend.observe()
    dq = state.q - q0
    assert np.sign(dq[i]) == sign and np.sign(state.dq[i]) == sign
    assert abs(dq[i]) > 5.0 * np.max(np.abs(np.delete(dq, i)))  # it is this joint that moves


@pytest.mark.parametrize("servo", ["step", "command"])
def test_the_hand_servo_runs_every_step_or_once_per_command(allegro, servo):
    """A target group's PD law on the state of every step (drives), or on the state when the
    command is applied, held (a controller's servo at its rate)."""
    from wholehand.backends.command import JointTargets

    backend = MujocoBackend(allegro, make_sphere(), hand_servo=servo)
    dofs = np.arange(allegro.nv)
    q0, dq0 = backend.observe().q, backend.observe().dq
    q_ref = np.clip(q0 + 0.3, allegro.q_lower, allegro.q_upper)
    kp, kd = np.full(allegro.nv, 0.2), np.full(allegro.nv, 0.01)
    bias = np.full(allegro.nv, 0.01)
    backend.apply(Command(bias, (JointTargets(dofs, q_ref, None, kp, kd),)))
    expected = np.clip(bias + kp * (q_ref - q0) - kd * dq0, -allegro.tau_max, allegro.tau_max)
    sent = []
    for _ in range(5):
        backend.step(0.001)
        mujoco.mj_forward(backend.model, backend.data)
        sent.append(backend.applied_torques())
    np.testing.assert_allclose(sent[0], expected, atol=1e-12)  # the first step: the same state
    moved = np.abs(np.diff(sent, axis=0)).max()
    assert moved == 0.0 if servo == "command" else moved > 1e-4


def test_an_unknown_hand_servo_is_named(allegro):
    with pytest.raises(ConfigError, match="hand_servo must be one of .*'command'"):
        MujocoBackend(allegro, make_sphere(), hand_servo="drives")


def test_step_counts_whole_timesteps(allegro):
    backend = MujocoBackend(allegro, make_sphere())
    backend.step(0.005)  # 0.005 / 0.001 is 5.000000000000001 in floating point
    assert backend.time == pytest.approx(0.005)
    backend.step(0.0005)  # rounds up to one step
    assert backend.time == pytest.approx(0.006)
    backend.step(0.0)
    assert backend.time == pytest.approx(0.006)


# --- object -------------------------------------------------------------------------------------
def test_gravity_off_by_default_on_by_option(allegro):
    obj = make_sphere()
    still = MujocoBackend(allegro, obj)
    z0 = still.observe().wMo[2, 3]
    still.step(0.3)
    assert still.observe().wMo[2, 3] == pytest.approx(z0, abs=1e-12)
    falling = MujocoBackend(allegro, obj, gravity=True)
    falling.step(0.3)
    drop = z0 - falling.observe().wMo[2, 3]
    assert drop == pytest.approx(0.5 * 9.81 * falling.time**2, rel=0.02)


def test_object_pose_round_trip(allegro):
    rng = np.random.default_rng(1)
    obj = make_ycb("077_rubiks_cube")
    backend = MujocoBackend(allegro, obj)
    for _ in range(3):
        wMo = pose_from_xyz_rpy(rng.uniform(-1, 1, 3), rng.uniform(-np.pi, np.pi, 3))
        q = rng.uniform(allegro.q_lower, allegro.q_upper)
        backend.reset(q, wMo)
        state = backend.observe()
        np.testing.assert_allclose(state.wMo, wMo, atol=1e-12)
        np.testing.assert_allclose(state.q, q, atol=0)
        assert state.stamp_q == state.stamp_object == backend.time == 0.0
    # the body frame is the mesh frame: the centre of mass sits at wMo @ com
    com_world = backend.data.xipos[backend.scene.object_body]
    np.testing.assert_allclose(com_world, wMo[:3, :3] @ obj.com + wMo[:3, 3], atol=1e-12)


# --- contacts -----------------------------------------------------------------------------------
def resting_box(allegro, mass=0.2, cone="elliptic"):
    """A box lying on the upturned palm, settled under gravity, fingers straight."""
    obj = make_box((0.05, 0.05, 0.05), mass=mass)
    wMo = pose_in_front_of_palm(obj, PALM_UP, gap=0.0005)
    backend = MujocoBackend(allegro, obj, wMo, np.zeros(16), gravity=True, wMb=PALM_UP, cone=cone)
    backend.step(0.3)
    return obj, backend


@pytest.mark.parametrize("cone", ["elliptic", "pyramidal"])
def test_ground_truth_contacts_resting_on_palm(allegro, cone):
    obj, backend = resting_box(allegro, cone=cone)
    contacts = backend.ground_truth_contacts()
    assert len(contacts) >= 3
    assert {allegro.link_names[i] for i in contacts.link} == {"palm_link"}
    # the box's bottom face touches the palm: outward normals point down (world -z)
    np.testing.assert_allclose(
        contacts.n_world, np.tile([0.0, 0.0, -1.0], (len(contacts), 1)), atol=1e-6
    )
    # the palm pushes the box: force on the object points into it (against its outward normal)
    assert np.all(np.einsum("ij,ij->i", contacts.f_world, contacts.n_world) < 0.0)
    assert np.all(contacts.f_normal > 0.0)
    # and, at rest, balances its weight
    np.testing.assert_allclose(contacts.f_world.sum(axis=0), [0.0, 0.0, obj.mass * 9.81], atol=1e-3)
    # points on the hand surface: on the palm's face plane, within the penetration
    palm_top = (PALM_UP @ np.array([PALM_FACE_X, 0.0, 0.0, 1.0]))[2]
    np.testing.assert_allclose(contacts.p_world[:, 2], palm_top, atol=1e-4)
    assert np.all(contacts.distance < 1e-4) and np.all(contacts.distance > -1e-3)
    contact_set = contacts.to_contact_set(allegro)
    assert len(contact_set) == len(contacts)


def test_ground_truth_contacts_balance_an_external_push(allegro):
    obj, backend = resting_box(allegro, mass=0.2)
    push = np.array([0.0, 0.0, -3.0])  # press the box onto the palm with 3 N more
    backend.apply_object_wrench(push, np.zeros(3))
    backend.step(0.2)
    contacts = backend.ground_truth_contacts()
    weight = np.array([0.0, 0.0, -obj.mass * 9.81])
    np.testing.assert_allclose(contacts.f_world.sum(axis=0), -(push + weight), atol=1e-3)


def test_contact_queries_do_not_change_the_trajectory(allegro):
    runs = []
    for query in (False, True):
        obj, backend = resting_box(allegro)
        backend.apply(Command.torques(squeeze(allegro, 0.15)))
        for _ in range(40):
            backend.step(0.002)
            if query:
                backend.ground_truth_contacts()
        runs.append(backend.data.qpos.copy())
    np.testing.assert_array_equal(runs[0], runs[1])


def test_mocap_base_moves_the_hand(allegro):
    backend = MujocoBackend(allegro, make_sphere(), base="mocap")
    wMb = pose_from_xyz_rpy([0.05, 0.0, 0.1], [0.0, 0.3, 0.0])
    backend.set_base_pose(wMb)
    np.testing.assert_allclose(backend.observe().wMb, wMb, atol=1e-12)
    backend.step(0.002)
    base = backend.scene.base_body
    np.testing.assert_allclose(backend.data.xpos[base], wMb[:3, 3], atol=1e-12)


def test_hand_hand_contacts_are_not_reported(allegro):
    backend = MujocoBackend(allegro, make_sphere())  # object far away
    q = allegro.neutral()
    q[allegro.joint_names.index("joint_12.0")] = allegro.q_upper[12]  # thumb across the palm
    tau = squeeze(allegro, 0.2)
    backend.reset(q, backend.observe().wMo)
    backend.apply(Command.torques(tau))
    backend.step(0.3)
    assert backend.data.ncon > 0  # fingertips on the palm
    assert len(backend.ground_truth_contacts()) == 0


# --- non-convex objects -------------------------------------------------------------------------
def cavity_point(mesh):
    """A point of the cup's cavity: outside the mesh, inside its hull, far from the surface."""
    lo, hi = mesh.bounds
    centre = 0.5 * (lo + hi)
    candidates = [
        np.array([centre[0], centre[1], lo[2] + f * (hi - lo)[2]]) for f in (0.5, 0.6, 0.7)
    ]
    for p in candidates:
        _, dist, _ = trimesh.proximity.closest_point(mesh, p[None])
        if not mesh.contains(p[None])[0] and dist[0] > 0.015:
            return p, float(dist[0])
    raise AssertionError("no cavity point found")


def probe_contacts(allegro, obj, collision, p_obj, radius):
    """Contacts between the object and a sphere probe placed at p_obj (object frame)."""
    scene = build_scene(allegro, obj, wMo=np.eye(4), options=SceneOptions(collision=collision))
    probe = scene.spec.worldbody.add_body(name="probe", pos=p_obj.tolist(), mocap=True)
    probe.add_geom(
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[radius, 0, 0],
        contype=HAND_BIT,
        conaffinity=OBJECT_BIT,
    )
    model = scene.spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    probe_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "probe")
    touching = [c for c in range(data.ncon) if probe_id in model.geom_bodyid[data.contact.geom[c]]]
    # a ray from the probe's centre straight up leaves the cup through its opening
    geomid = np.zeros(1, dtype=np.int32)
    up = mujoco.mj_ray(model, data, p_obj, np.array([0.0, 0.0, 1.0]), None, 1, probe_id, geomid)
    return len(touching), up


def test_cup_cavity_is_free_space_unlike_its_convex_hull(allegro):
    cup = make_ycb("065-f_cups")
    p, clearance = cavity_point(cup.mesh)
    radius = 0.5 * clearance
    n_dec, ray_dec = probe_contacts(allegro, cup, "decomposition", p, radius)
    n_hull, ray_hull = probe_contacts(allegro, cup, "hull", p, radius)
    assert n_dec == 0 and n_hull > 0
    # upwards the decomposed cup is open (no hit), the hull is hit at its distance from the top
    assert ray_dec == -1.0
    assert 0.0 < ray_hull < cup.mesh.bounds[1][2] - p[2] + 1e-6


# --- convex decomposition cache -----------------------------------------------------------------
def test_convex_decomposition_is_cached_by_content(fresh_cache):
    # an L-shaped prism (watertight, 20 faces): its hull would fill the inner corner
    outline = np.array([[0, 0], [3, 0], [3, 1], [1, 1], [1, 3], [0, 3]], dtype=float) * 0.02
    triangles = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]])
    mesh = trimesh.creation.extrude_triangulation(outline, triangles, 0.02)
    params = {"threshold": 0.05, "resolution": 500, "mcts_iterations": 30, "mcts_nodes": 5}
    first = convex_decomposition(mesh, **params)
    assert first.source == "computed" and len(first) >= 2
    again = convex_decomposition(mesh, **params)
    assert again.source == "cache" and again.key == first.key
    np.testing.assert_array_equal(again.vertices, first.vertices)
    other = convex_decomposition(mesh, **{**params, "threshold": 0.2})
    assert other.key != first.key
    with pytest.raises(ConfigError, match="unknown CoACD parameters"):
        convex_decomposition(mesh, thresh=0.1)


def test_every_object_with_shipped_grasps_ships_its_decomposition(allegro):
    """Shipped grasps were made on these decompositions: MuJoCo must not need CoACD for them."""
    names = sorted(set(PAPER_OBJECTS) | set(objects_with_grasps("allegro_right")))
    missing = [n for n in names if not shipped_decomposition_file(n, make_ycb(n).mesh).is_file()]
    assert not missing
    for name in PAPER_OBJECTS:
        assert convex_decomposition(make_ycb(name).mesh, name=name).source == "shipped"


# --- bad input ----------------------------------------------------------------------------------
def test_bad_arguments_raise_config_errors(allegro):
    obj = make_sphere()
    with pytest.raises(ConfigError, match="unknown options"):
        MujocoBackend(allegro, obj, conee="elliptic")
    with pytest.raises(ConfigError, match="timestep"):
        MujocoBackend(allegro, obj, timestep=-1e-3)
    with pytest.raises(ConfigError, match="solref"):
        MujocoBackend(allegro, obj, timestep=5e-3)
    with pytest.raises(ConfigError, match="cone"):
        MujocoBackend(allegro, obj, cone="round")
    bad = np.eye(4)
    bad[0, 3] = np.nan
    with pytest.raises(ConfigError, match="wMo"):
        MujocoBackend(allegro, obj, wMo_init=bad)
    backend = MujocoBackend(allegro, obj)
    with pytest.raises(ConfigError, match="tau"):
        backend.apply(Command.torques(np.zeros(3)))
    with pytest.raises(ConfigError, match="NaN"):
        backend.apply(Command.torques(np.full(allegro.nv, np.nan)))
    with pytest.raises(ConfigError, match="duration"):
        backend.step(-0.1)
    with pytest.raises(ConfigError, match="mocap"):
        backend.set_base_pose(np.eye(4))
    with pytest.raises(ConfigError, match="force_world"):
        backend.apply_object_wrench(np.zeros(2), np.zeros(3))


def test_unknown_object_name_raises(allegro):
    with pytest.raises(WholehandError, match="no_such_object"):
        MujocoBackend(allegro, "no_such_object")


def test_bad_object_properties_raise(allegro):
    obj = make_sphere()
    for field, value, match in [
        ("mass", 0.0, "mass"),
        ("inertia", -np.eye(3), "positive definite"),
        ("friction", -1.0, "friction"),
    ]:
        broken = copy.copy(obj)
        object.__setattr__(broken, field, value)
        with pytest.raises(ConfigError, match=match):
            build_scene(allegro, broken)


def test_missing_torque_limits_raise(allegro):
    hand = copy.copy(allegro)
    hand.tau_max = np.zeros(allegro.nv)
    with pytest.raises(ConfigError, match="torque limit"):
        build_scene(hand, make_sphere())


def test_broken_urdf_raises_asset_error(allegro, tmp_path):
    text = allegro.config.model_path.read_text()
    broken = tmp_path / "broken.urdf"
    broken.write_text(text.replace('<box size="0.0196 0.0275 0.0164"/>', '<box size="0 0 0"/>', 1))
    hand = copy.copy(allegro)
    hand.config = dataclasses.replace(allegro.config, model_path=broken)
    with pytest.raises(AssetError, match="broken.urdf|cannot compile"):
        build_scene(hand, make_sphere())
    missing = tmp_path / "missing_mesh.urdf"
    mesh = '<mesh filename="package://nowhere/none.stl"/>'
    missing.write_text(text.replace('<box size="0.0196 0.0275 0.0164"/>', mesh, 1))
    hand.config = dataclasses.replace(allegro.config, model_path=missing)
    with pytest.raises(AssetError, match="none.stl"):
        build_scene(hand, make_sphere())


def test_the_clock_keeps_running_when_mujoco_resets_a_diverged_simulation(allegro):
    """MuJoCo resets its data, time included, when it diverges; the backend's clock (and so
    the loop's schedule and the joint history) goes on."""
    backend = MujocoBackend(allegro, make_sphere())
    backend.step(0.1)
    backend.observe()
    backend.data.qvel[:] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        backend.step(0.005)
    assert backend.warnings()["bad_qvel"] == 1 and backend.data.time < 0.01
    assert backend.time == pytest.approx(0.105, abs=1e-12)
    obs = backend.observe()
    assert obs.stamp_q == backend.time and obs.history.newest_stamp == backend.time
    backend.reset(allegro.neutral(), obs.wMo)
    assert backend.time == 0.0 and len(backend.history) == 0
