"""A MuJoCo scene of one hand and one free object, built with ``mujoco.MjSpec``.

The hand comes from its URDF or MJCF (:mod:`wholehand_plugins.mujoco.hand_spec`: every
Pinocchio link has a MuJoCo body of the same name, visual-only geometry is discarded) and is then
edited in the spec:

- its root link (the Pinocchio base ``b``) is welded to the world at ``hand.wMb`` (``base="fixed"``)
  or is a mocap body that can be moved kinematically (``base="mocap"``);
- every joint gets the damping and armature of ``[simulation]`` in hand.toml (the URDF's own
  ``<dynamics>`` damping and friction are dropped) and keeps its URDF position limits; an
  assembly's arm joints get ``[assembly] arm_armature`` instead;
- every actuated joint, and every arm joint of an assembly, gets a ``motor`` actuator,
  ctrl = force = torque [N*m], with ``ctrlrange`` and ``forcerange`` +-``hand.tau_max``;
- URDF ``<mimic>`` couplings are joint equality constraints (MuJoCo's URDF importer makes them;
  hand.toml's ``[joints] coupled`` adds its own the same way), as stiff as the contacts
  (``solref``); the followers have no actuator, so an actuator torque drives the leader and its
  followers together;
- locked joints of hand.toml are removed and their bodies fixed at the locked value.

The object is a body named ``"object"`` with a free joint whose body frame is the object frame
(:mod:`wholehand_plugins.mujoco.object_spec`).

The contact model and the scene options: :mod:`wholehand_plugins.mujoco.scene_options`.

Indexing: MuJoCo's joint order differs from Pinocchio's, so positions, velocities and controls are
mapped by joint NAME (:attr:`HandObjectScene.qpos_index` etc.), never by position.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np
import numpy.typing as npt

from wholehand import defaults
from wholehand.backends.table import TABLE_GEOM, Table
from wholehand.errors import AssetError, ConfigError
from wholehand.models.poses import check_pose

from .hand_spec import (
    add_declared_couplings,
    load_hand_spec,
    mujoco_link_name,
    weld_locked_joints,
)
from .object_spec import add_object
from .poses import set_spec_pose
from .scene_options import (
    CONES,
    HAND_BIT,
    OBJECT_BIT,
    OBJECT_BODY,
    OBJECT_JOINT,
    TABLE_BIT,
    WRIST_JOINT,
    WRIST_TARGET,
    SceneOptions,
)

if TYPE_CHECKING:
    from wholehand.models.hand import HandModel
    from wholehand.models.objects import ObjectModel

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]


@dataclass
class HandObjectScene:
    """A compiled hand-object scene and the index maps between MuJoCo and Pinocchio.

    Index arrays are in Pinocchio order: entry i of ``qpos_index`` is the MuJoCo ``qpos`` address of
    Pinocchio configuration coordinate i.
    """

    spec: mujoco.MjSpec
    model: mujoco.MjModel
    options: SceneOptions
    joint_names: list[str]
    """(n_q,) hand joint names in Pinocchio order (``hand.joint_names``)."""
    qpos_index: IntArray
    """(n_q,) MuJoCo qpos address of each Pinocchio configuration coordinate."""
    qvel_index: IntArray
    """(n_v,) MuJoCo qvel (dof) address of each Pinocchio velocity coordinate."""
    ctrl_index: IntArray
    """(n_v,) MuJoCo actuator id of each Pinocchio velocity coordinate, -1 where not actuated."""
    tau_max: FloatArray
    """(n_v,) torque limits [N*m], Pinocchio order (0 where not actuated)."""
    base_body: int
    """MuJoCo body id of the hand base (root link)."""
    object_body: int
    """MuJoCo body id of the object."""
    object_qpos: int
    """qpos address of the object's free joint: [x y z qw qx qy qz]."""
    object_qvel: int
    """qvel address of the object's free joint: [v (world), omega (body frame)]."""
    geom_link: IntArray
    """(ngeom,) index into ``hand.link_names`` of each hand geom's link, -1 for other geoms."""
    geom_is_object: BoolArray
    """(ngeom,) True for the object's collision geoms."""
    link_body: IntArray
    """(L,) MuJoCo body id of each link of ``hand.link_names``."""
    decomposition_parts: int = 0
    """Number of convex parts the object collides as (0 for primitives)."""


# --- hand ---------------------------------------------------------------------------------------
def _check_hand(hand: HandModel) -> None:
    tau = np.asarray(hand.tau_max, dtype=float)
    act = np.asarray(hand.actuated_dofs, dtype=bool)
    if tau.shape != (hand.nv,) or act.shape != (hand.nv,):
        raise ConfigError(
            f"hand {hand.name!r}: tau_max and actuated_dofs must have shape ({hand.nv},), got "
            f"{tau.shape} and {act.shape}"
        )
    bad = [hand.joint_names[i] for i in np.flatnonzero(act & ~(np.isfinite(tau) & (tau > 0)))]
    if bad:
        raise ConfigError(
            f"{hand.config.path}: actuated joints {bad} have no positive torque limit; set "
            "[joints] torque_limit = { default = ..., <joint> = ... } [N*m] in hand.toml"
        )
    if not act.any():
        raise ConfigError(f"{hand.config.path}: hand {hand.name!r} has no actuated joint")


def _set_joints(spec: mujoco.MjSpec, hand: HandModel) -> None:
    """Every joint's damping and armature from hand.toml (an arm's its own), no friction."""
    arm_joints = set(hand.config.arm_joints)
    for joint in spec.joints:
        joint.damping = [hand.config.damping, 0.0, 0.0]  # linear viscous damping only
        arm = joint.name in arm_joints
        joint.armature = hand.config.arm_armature if arm else hand.config.armature
        joint.frictionloss = 0.0


def _set_geoms(spec: mujoco.MjSpec, opts: SceneOptions, mu: float) -> None:
    """Every hand geom named after its link, in the hand's collision group, with the scene's
    contact parameters and friction ``mu``."""
    for body in spec.bodies:  # URDF geoms are nameless: name them after their link
        for k, geom in enumerate(body.geoms):
            geom.name = geom.name or f"{body.name}/collision_{k}"
    hand_affinity = OBJECT_BIT | (HAND_BIT if opts.self_collision else 0)
    for geom in spec.geoms:
        geom.contype = HAND_BIT
        geom.conaffinity = hand_affinity
        geom.condim = opts.condim
        geom.friction = [mu, 0.005, 0.0001]
        geom.solref = list(opts.solref)
        geom.solimp = list(opts.solimp)
        geom.priority = 0
        geom.margin = 0.0
        geom.gap = 0.0


def _edit_hand(
    spec: mujoco.MjSpec, hand: HandModel, wMb: FloatArray, opts: SceneOptions, mu: float
) -> None:
    roots = list(spec.worldbody.bodies)
    if len(roots) != 1:
        raise AssetError(
            f"{hand.config.model_path}: expected one root link (body), MuJoCo found "
            f"{[b.name for b in roots]}"
        )
    base = roots[0]  # the base frame b; an MJCF root body's own pose is dropped, as Pinocchio does
    set_spec_pose(base, wMb)
    base.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT  # the quaternion just set
    if opts.base == "mocap":
        base.mocap = True
    elif opts.base == "floating":
        target = spec.worldbody.add_body(name=WRIST_TARGET, mocap=True)
        set_spec_pose(target, wMb)
        target.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT
    weld_locked_joints(spec, hand)
    add_declared_couplings(spec, hand)
    _set_joints(spec, hand)
    _set_geoms(spec, opts, mu)
    for equality in spec.equalities:  # couplings: an MJCF's own, or URDF <mimic> as imported
        equality.solref = list(opts.solref)
    if opts.base == "floating":  # after the joint edits: the free joint gets no damping
        base.add_freejoint(name=WRIST_JOINT)
        weld = spec.add_equality(
            type=mujoco.mjtEq.mjEQ_WELD,
            objtype=mujoco.mjtObj.mjOBJ_BODY,
            name1=WRIST_TARGET,
            name2=base.name,
        )
        weld.solref = list(opts.wrist_solref)
        # anchor (3), relative pose (position 3, quaternion 4), torque scale, unused: the base
        # sits exactly on its target (MjSpec's default data is not a zero offset)
        weld.data = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0])
    for dof in np.flatnonzero(hand.actuated_dofs | hand.arm_dofs):
        name = hand.joint_names[int(dof)]
        tau = float(hand.tau_max[int(dof)])
        act = spec.add_actuator(
            name=f"motor_{name}", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT
        )
        act.set_to_motor()
        act.ctrllimited = True
        act.ctrlrange = [-tau, tau]
        act.forcelimited = True
        act.forcerange = [-tau, tau]


# --- index maps ---------------------------------------------------------------------------------
def _name2id(model: mujoco.MjModel, kind: mujoco.mjtObj, name: str) -> int:
    return int(mujoco.mj_name2id(model, kind, name))


def _index_maps(model: mujoco.MjModel, hand: HandModel) -> dict[str, Any]:
    pin_model = hand.model
    qpos_index = np.zeros(hand.nq, dtype=np.intp)
    qvel_index = np.zeros(hand.nv, dtype=np.intp)
    ctrl_index = np.full(hand.nv, -1, dtype=np.intp)
    for name in hand.joint_names:
        jid = _name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid < 0:
            raise AssetError(f"joint {name!r} of the Pinocchio model has no MuJoCo joint")
        pj = pin_model.joints[pin_model.getJointId(name)]
        qpos_index[pj.idx_q] = model.jnt_qposadr[jid]
        qvel_index[pj.idx_v] = model.jnt_dofadr[jid]
        aid = _name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, f"motor_{name}")
        if aid >= 0:
            ctrl_index[pj.idx_v] = aid
    link_body = np.array(
        [_name2id(model, mujoco.mjtObj.mjOBJ_BODY, mujoco_link_name(n)) for n in hand.link_names],
        dtype=np.intp,
    )
    missing = [n for n, b in zip(hand.link_names, link_body, strict=True) if b < 0]
    if missing:
        raise AssetError(f"links {missing} of hand {hand.name!r} have no MuJoCo body")
    body_link = {int(b): i for i, b in enumerate(link_body)}
    object_body = _name2id(model, mujoco.mjtObj.mjOBJ_BODY, OBJECT_BODY)
    geom_link = np.full(model.ngeom, -1, dtype=np.intp)
    for g in range(model.ngeom):
        body = int(model.geom_bodyid[g])
        if body == object_body:
            continue
        while body > 0 and body not in body_link:  # geoms of links without sampled geometry
            body = int(model.body_parentid[body])
        geom_link[g] = body_link.get(body, -1)
    geom_is_object = (model.geom_bodyid == object_body) & (model.geom_contype != 0)
    jid = _name2id(model, mujoco.mjtObj.mjOBJ_JOINT, OBJECT_JOINT)
    return {
        "qpos_index": qpos_index,
        "qvel_index": qvel_index,
        "ctrl_index": ctrl_index,
        "link_body": link_body,
        "geom_link": geom_link,
        "geom_is_object": geom_is_object,
        "object_body": object_body,
        "object_qpos": int(model.jnt_qposadr[jid]),
        "object_qvel": int(model.jnt_dofadr[jid]),
        "base_body": next(
            b
            for b in range(1, model.nbody)
            if model.body_parentid[b] == 0
            and b != object_body
            and model.body(b).name != WRIST_TARGET
        ),
    }


def _exclude_touching_pairs(
    spec: mujoco.MjSpec, hand: HandModel, qpos_index: IntArray, object_body: int
) -> int:
    """Exclude hand body pairs that touch in the neutral or zero configuration (they overlap by
    construction, not by motion) and the base with its children (which MuJoCo's parent filter
    misses for a base welded to the world). Returns the number of pairs excluded."""
    model = spec.compile()
    data = mujoco.MjData(model)
    name = functools.partial(mujoco.mj_id2name, model, mujoco.mjtObj.mjOBJ_BODY)
    pairs: set[tuple[str, str]] = set()
    for b in range(1, model.nbody):
        parent = int(model.body_parentid[b])
        if parent > 0 and model.body_parentid[parent] == 0 and parent != object_body:
            pairs.add((min(name(b), name(parent)), max(name(b), name(parent))))
    for q in (hand.neutral(), np.clip(np.zeros(hand.nq), hand.q_lower, hand.q_upper)):
        data.qpos[qpos_index] = q
        mujoco.mj_forward(model, data)
        for c in range(data.ncon):
            b1, b2 = (int(model.geom_bodyid[g]) for g in data.contact.geom[c])
            if object_body not in (b1, b2):
                n1, n2 = name(b1), name(b2)
                pairs.add((min(n1, n2), max(n1, n2)))
    for n1, n2 in sorted(pairs):
        spec.add_exclude(bodyname1=n1, bodyname2=n2)
    return len(pairs)


def _compile(spec: mujoco.MjSpec, what: str) -> mujoco.MjModel:
    try:
        return spec.compile()
    except ValueError as err:
        raise AssetError(
            f"MuJoCo cannot compile the scene of {what}: {err}; check the hand URDF, the object "
            "mesh and the scene options"
        ) from err


def build_scene(
    hand: HandModel,
    obj: ObjectModel,
    wMo: FloatArray | None = None,
    options: SceneOptions | None = None,
    wMb: FloatArray | None = None,
) -> HandObjectScene:
    """Build and compile the MuJoCo scene of ``hand`` and ``obj``.

    Args:
        hand: the hand model (URDF, limits, mount pose ``hand.wMb``).
        obj: the object model; its frame becomes the frame of body ``"object"``.
        wMo: (4, 4) initial pose of the object frame in the world; default: 0.5 m below the hand
            base, clear of the hand.
        options: physics settings (:class:`SceneOptions`).
        wMb: (4, 4) pose of the hand base in the world; default: the mount pose ``hand.wMb``.
    """
    opts = options or SceneOptions()
    _check_hand(hand)
    wMb = check_pose(hand.wMb if wMb is None else wMb, "wMb")
    wMo = default_object_pose(wMb) if wMo is None else check_pose(wMo, "wMo")
    mu = float(obj.friction) if opts.friction is None else float(opts.friction)
    if not (math.isfinite(mu) and mu >= 0):
        raise ConfigError(f"object {obj.name!r}: friction must be a number >= 0, got {mu!r}")

    spec = load_hand_spec(hand)
    spec.modelname = f"{hand.name}_{obj.name}".replace(":", "_")
    _edit_hand(spec, hand, wMb, opts, mu)
    parts = add_object(spec, obj, wMo, opts, mu)
    if opts.table is not None:
        add_table(
            spec.worldbody,
            opts.table,
            TABLE_BIT,
            HAND_BIT | OBJECT_BIT,
            condim=opts.condim,
            solref=list(opts.solref),
            solimp=list(opts.solimp),
        )

    o = spec.option
    o.timestep = float(opts.timestep)
    o.gravity = list(defaults.GRAVITY_VECTOR) if opts.gravity else [0.0, 0.0, 0.0]
    o.cone = CONES[opts.cone]
    o.impratio = float(opts.impratio)
    o.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    o.solver = mujoco.mjtSolver.mjSOL_NEWTON
    o.iterations = int(opts.iterations)
    o.tolerance = 1e-8

    what = f"hand {hand.name!r} ({hand.config.model_path}) with object {obj.name!r}"
    model = _compile(spec, what)
    maps = _index_maps(model, hand)
    if opts.self_collision:
        n = _exclude_touching_pairs(spec, hand, maps["qpos_index"], maps["object_body"])
        if n:
            model = _compile(spec, what)
            maps = _index_maps(model, hand)
    tau_max = np.where(hand.actuated_dofs | hand.arm_dofs, hand.tau_max, 0.0).astype(float)
    return HandObjectScene(
        spec=spec,
        model=model,
        options=opts,
        joint_names=list(hand.joint_names),
        tau_max=tau_max,
        decomposition_parts=parts,
        **maps,
    )


def default_object_pose(wMb: FloatArray) -> FloatArray:
    """(4, 4) object pose used when none is given: 0.5 m below the hand base, world axes."""
    wMo = np.eye(4)
    wMo[:3, 3] = np.asarray(wMb)[:3, 3] + np.array([0.0, 0.0, -0.5])
    return wMo


def add_table(body: Any, table: Table, contype: int, conaffinity: int, **geom: Any) -> Any:
    """Add ``table`` to ``body`` (an ``MjsBody`` at the world origin: the world body or a static
    child of it) as the box geom :data:`~wholehand.backends.table.TABLE_GEOM`; returns the
    geom."""
    return body.add_geom(
        name=TABLE_GEOM,
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=table.half_extents.tolist(),
        pos=table.box_centre.tolist(),
        contype=contype,
        conaffinity=conaffinity,
        friction=[table.friction, 0.005, 0.0001],
        rgba=[0.55, 0.45, 0.35, 1.0],
        **geom,
    )
