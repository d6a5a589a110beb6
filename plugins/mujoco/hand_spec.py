"""The hand as a ``mujoco.MjSpec``, before the scene adds the object and edits the hand.

A URDF is converted (mesh URIs made absolute, visuals removed, fixed links kept as bodies); an
MJCF is loaded as it is and stripped of what belongs to a scene of its own. Locked joints of
hand.toml are welded at their values, as the hand model fixes them.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from wholehand.errors import AssetError
from wholehand.models.mesh_files import resolve_mesh_uri

if TYPE_CHECKING:
    from wholehand.models.hand import HandModel


def _urdf_for_mujoco(hand: HandModel) -> str:
    """The hand's URDF as a string MuJoCo can compile: absolute mesh paths, visuals removed (only
    collision geometry is simulated), and a ``<mujoco><compiler/></mujoco>`` block (balanced
    inertias, fixed links kept as bodies)."""
    cfg = hand.config
    try:
        root = ET.parse(cfg.model_path).getroot()
    except (ET.ParseError, OSError) as err:
        raise AssetError(f"{cfg.model_path}: cannot read the URDF: {err}") from err
    for link in root.iter("link"):
        for visual in list(link.findall("visual")):
            link.remove(visual)
    _rename_world_root(root)
    for mesh in root.iter("mesh"):
        uri = mesh.get("filename", "")
        path = resolve_mesh_uri(uri, cfg.model_path, cfg.package_dirs)
        if path is None:
            raise AssetError(
                f"{cfg.model_path}: collision mesh {uri!r} not found in the package directories "
                f"{[str(d) for d in cfg.package_dirs]}; install the package that ships it"
            )
        mesh.set("filename", str(path.resolve()))
    for old in root.findall("mujoco"):
        root.remove(old)
    block = ET.SubElement(root, "mujoco")
    ET.SubElement(
        block,
        "compiler",
        balanceinertia="true",
        fusestatic="false",
        strippath="false",
    )
    return ET.tostring(root, encoding="unicode")


WORLD_ROOT = "wholehand_world_root"
"""MuJoCo's name for a URDF root link named ``world`` (:func:`_rename_world_root`)."""


def mujoco_link_name(link: str) -> str:
    """The MuJoCo body name of a URDF link."""
    return WORLD_ROOT if link == "world" else link


def _rename_world_root(root: ET.Element) -> None:
    """MuJoCo's URDF importer takes a link named ``world`` for its world body and hangs the
    links below it from the world directly, so the root's placement of its children (a 90 deg
    turn, say) would be lost when the scene mounts the hand; Pinocchio keeps that link as the
    hand's base. Renamed (:func:`mujoco_link_name`), it stays a body of the hand."""
    for element in (*root.iter("link"), *root.iter("parent"), *root.iter("child")):
        for key in ("name", "link"):
            if element.get(key) == "world":
                element.set(key, mujoco_link_name("world"))


def _mjcf_hand_spec(hand: HandModel) -> mujoco.MjSpec:
    """An MJCF hand as the scene needs it (its one root body, or ``root_body``, is the hand
    base, as a URDF's root link; :mod:`wholehand.models.mjcf_file`): its actuators, keyframes
    and sensors removed (the scene adds its own motors and an object), static world geoms (a
    floor) removed, and its visual-only geoms (contype = conaffinity = 0, as Pinocchio reads
    them) removed."""
    path = hand.parsed_model_path
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except ValueError as err:
        raise AssetError(f"{path}: MuJoCo cannot load this MJCF: {err}") from err
    for element in [*spec.actuators, *spec.keys, *spec.sensors, *spec.worldbody.geoms]:
        spec.delete(element)
    for geom in list(spec.geoms):
        if geom.contype == 0 and geom.conaffinity == 0:
            spec.delete(geom)
    return spec


def load_hand_spec(hand: HandModel) -> mujoco.MjSpec:
    if hand.config.model_format == "mjcf":
        spec = _mjcf_hand_spec(hand)
        spec.compiler.discardvisual = False
        return spec
    try:
        spec = mujoco.MjSpec.from_string(_urdf_for_mujoco(hand))
    except ValueError as err:
        raise AssetError(
            f"{hand.config.model_path}: MuJoCo cannot parse this URDF: {err}; check the URDF "
            "(hand.toml names it) and its mesh files"
        ) from err
    # The URDF's visuals are already stripped; keep the visual-only object mesh if one is added.
    spec.compiler.discardvisual = False
    return spec


def add_declared_couplings(spec: mujoco.MjSpec, hand: HandModel) -> None:
    """A joint equality for each coupling of hand.toml's ``[joints] coupled`` (the model file's
    own are in the spec already): MuJoCo's ``q_f - ref_f = a0 + a1 (q_l - ref_l)`` with
    ``a1 = multiplier`` and ``a0 = offset + multiplier ref_l - ref_f``. Couplings between two
    locked joints are dropped: both are welded."""
    for follower, m in hand.config.coupled_joints.items():
        if follower in hand.config.locked_joints:
            continue
        joints = [spec.joint(name) for name in (follower, m.leader)]
        if any(j is None for j in joints):
            raise AssetError(
                f"{hand.config.model_path}: coupled joints {follower!r} and {m.leader!r} of "
                f"{hand.config.path.name} have no MuJoCo joint"
            )
        ref_f, ref_l = (float(j.ref) for j in joints)
        equality = spec.add_equality(
            type=mujoco.mjtEq.mjEQ_JOINT,
            objtype=mujoco.mjtObj.mjOBJ_JOINT,
            name1=follower,
            name2=m.leader,
        )
        data = np.zeros_like(np.asarray(equality.data, dtype=float))  # mjNEQDATA values
        data[:2] = (m.offset + m.multiplier * ref_l - ref_f, m.multiplier)
        equality.data = data


def _drop_tendons_of(spec: mujoco.MjSpec, joints: set[str]) -> None:
    """Delete the tendons of ``spec`` that wrap one of ``joints``."""
    if not joints or not spec.tendons:
        return
    model = spec.copy().compile()  # the spec keeps no list of a tendon's wraps; the model does
    tendons = list(spec.tendons)
    for t in range(model.ntendon):
        start = int(model.tendon_adr[t])
        for w in range(start, start + int(model.tendon_num[t])):
            is_joint = model.wrap_type[w] == mujoco.mjtWrap.mjWRAP_JOINT
            if is_joint and model.joint(int(model.wrap_objid[w])).name in joints:
                spec.delete(tendons[t])
                break


def weld_locked_joints(spec: mujoco.MjSpec, hand: HandModel) -> None:
    """Replace each locked joint by a fixed offset of its body at the locked value, as the
    hand model does: rotate the body about a hinge's axis, or shift it along a slide's. Tendons
    that wrap a locked joint go with it (their actuators go with the file's others)."""
    _drop_tendons_of(spec, set(hand.config.locked_joints))
    for name, value in hand.config.locked_joints.items():
        joint = spec.joint(name)
        if joint is None:
            raise AssetError(f"{hand.config.model_path}: locked joint {name!r} has no MuJoCo joint")
        body, axis = joint.parent, np.asarray(joint.axis, dtype=float)
        axis = axis / np.linalg.norm(axis)
        quat = np.asarray(body.quat, dtype=float)
        if joint.type == mujoco.mjtJoint.mjJNT_HINGE:
            turn, turned = np.zeros(4), np.zeros(4)
            mujoco.mju_axisAngle2Quat(turn, axis, float(value))
            mujoco.mju_mulQuat(turned, quat, turn)
            body.quat = turned.tolist()
        else:  # slide: the axis is in the body frame
            shift = np.zeros(3)
            mujoco.mju_rotVecQuat(shift, axis * float(value), quat)
            body.pos = (np.asarray(body.pos, dtype=float) + shift).tolist()
        spec.delete(joint)
