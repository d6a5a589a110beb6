"""Grasps of published synthesisers converted to the project's grasp files.

Three formats, as their public repositories write them (all NumPy ``.npy`` files of pickled
Python objects, read by :func:`~wholehand.grasps.npy_reader.load_npy`, which builds arrays,
dicts, lists, numbers and strings only and runs nothing a file names):

- ``dexgraspnet`` (DexGraspNet, ``grasp_generation/scripts/generate_grasps.py``): one file per
  object, a list of dicts ``{"scale": s, "qpos": {...}, ...}``; ``qpos`` names every joint and
  holds the hand root's translation ``WRJTx/y/z`` [m] and rotation ``WRJRx/y/z`` (static-axis
  x-y-z Euler angles [rad]) in the frame of the object mesh scaled by ``s``.
- ``dexonomy`` (Dexonomy and DexGraspBench): one dict per grasp (or the same keys with a
  leading batch axis), ``grasp_qpos`` / ``pregrasp_qpos`` / ``squeeze_qpos`` each ``[x, y, z,
  qw, qx, qy, qz, joints...]``: the free hand root in the world, then the joints in the order of
  the hand's MJCF (or of ``joint_names`` when the dict has it); ``obj_pose`` ``[x, y, z, qw, qx,
  qy, qz]`` the object in the world and ``obj_scale`` its mesh's scale.
- ``bodex`` (BODex): one dict per object with ``robot_pose`` of shape (1, B, stages, 7 + n):
  per grasp the pre-grasp (stage 0) and the grasp (stage 1) as ``[x, y, z, qw, qx, qy, qz,
  joints...]`` in the world, joints in the order of the hand's cuRobo configuration;
  ``obj_pose`` (1, 7) and ``obj_scale`` (1,).

A grasp becomes the hand base pose in the object frame, ``oMb = oMr rMb`` (``r`` the file's
hand root, ``rMb`` where this project's base frame sits in it: identity unless the two
descriptions of the hand place their roots differently), and its joint angles by this hand's
joint names (the file's names, renamed by a joint map where they differ). A file's object must
be this object at the scale the file names (``object_scale``); grasps made at other scales are
skipped with the reason, as are grasps with a pose or joint angle that is not finite, a
quaternion whose norm differs from 1 by more than :data:`QUATERNION_TOL` (normalising it would
store another grasp), and a joint more than :data:`~wholehand.grasps.store.LIMIT_SLACK` outside
its limits. A file whose fields have the wrong type or shape is refused with the field named.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from wholehand.errors import ConfigError
from wholehand.grasps.npy_reader import load_npy
from wholehand.grasps.store import LIMIT_SLACK, Grasp
from wholehand.models.hand import HandModel
from wholehand.models.poses import inverse

FloatArray = npt.NDArray[np.float64]

FORMATS = ("dexgraspnet", "dexonomy", "bodex")
"""The formats :func:`import_grasps` reads."""
SCALE_TOL = 1e-6
"""Relative difference of a grasp's object scale from the expected one still accepted [-]."""
DEXGRASPNET_ROOT = ("WRJTx", "WRJTy", "WRJTz", "WRJRx", "WRJRy", "WRJRz")
"""DexGraspNet's names of the hand root's translation and rotation in ``qpos``."""
QUATERNION_TOL = 1e-3
"""Largest difference of a pose quaternion's norm from 1 accepted [-]."""


@dataclass(frozen=True)
class ForeignGrasp:
    """One grasp as a file states it, before it is mapped onto a hand."""

    oMr: FloatArray
    """(4, 4) the file's hand root in the object frame [m]."""
    q: dict[str, float]
    """Joint angles [rad] by the file's joint names."""
    scale: float
    """Scale of the object mesh the grasp was made on [-]."""
    pre_oMr: FloatArray | None = None
    """(4, 4) the pre-grasp's hand root in the object frame, where the file has one."""
    pre_q: dict[str, float] | None = None
    """The pre-grasp's joint angles, where the file has them."""
    where: str = ""
    """File and entry, for messages."""
    problem: str = ""
    """Why the grasp cannot be used (a pose not finite, a quaternion not of unit norm), or
    empty; the poses are then meaningless."""


def pose_problem(xyz_wxyz: npt.ArrayLike, what: str) -> str:
    """Why ``[x, y, z, qw, qx, qy, qz]`` is not a pose (``what`` names it), or empty."""
    v = np.asarray(xyz_wxyz, dtype=float)
    if not np.isfinite(v).all():
        return f"{what} not finite"
    norm = float(np.linalg.norm(v[3:7]))
    if abs(norm - 1.0) > QUATERNION_TOL:
        return f"{what} quaternion of norm {norm:.3g}, not 1"
    return ""


def pose_matrix(xyz_wxyz: npt.ArrayLike) -> FloatArray:
    """(4, 4) from ``[x, y, z, qw, qx, qy, qz]`` (MuJoCo's free-joint order), a unit
    quaternion (:func:`pose_problem` says whether it is one)."""
    v = np.asarray(xyz_wxyz, dtype=float)
    M = np.eye(4)
    M[:3, :3] = Rotation.from_quat([v[4], v[5], v[6], v[3]]).as_matrix()
    M[:3, 3] = v[:3]
    return M


def _numbers(value: Any, where: str, field: str, shape: str = "") -> FloatArray:
    """``value`` as floats, or an error naming the grasp and the field."""
    try:
        out = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        text = repr(value)
        text = text if len(text) <= 60 else text[:57] + "..."
        expected = f" of shape {shape}" if shape else ""
        raise ConfigError(f"{where}: {field} is not numbers{expected}: {text}") from None
    return out


def _shape_error(where: str, field: str, got: tuple[int, ...], expected: str) -> ConfigError:
    return ConfigError(f"{where}: {field} has shape {got}, expected {expected}")


def _item(data: Any, path: Path, what: str) -> dict[str, Any]:
    """The dict a ``np.save``-d dict became (a 0-d object array)."""
    if isinstance(data, np.ndarray) and data.dtype == object and data.shape == ():
        data = data.item()
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected {what} (a dict saved with np.save), got {type(data)}")
    return data


def _names(
    joint_names: Sequence[str] | None, stored: Any, n: int, path: Path, fmt: str
) -> list[str]:
    """The file's joint order: its own ``joint_names``, else the caller's."""
    names = [str(n) for n in stored] if stored is not None else list(joint_names or [])
    if not names:
        raise ConfigError(
            f"{path}: a {fmt} file lists its joints in the order of the hand's "
            f"{'MJCF' if fmt == 'dexonomy' else 'cuRobo configuration'} without naming them; "
            "give that order with --joint-names a,b,c (Python: joint_names=[...])"
        )
    if len(names) != n:
        raise ConfigError(
            f"{path}: the file has {n} joint values per grasp, the joint names are {len(names)} "
            f"({names}); give the file's joint order"
        )
    return names


def read_dexgraspnet(path: Path) -> list[ForeignGrasp]:
    """The grasps of a DexGraspNet file (module docstring)."""
    data = load_npy(path)
    entries = list(data) if isinstance(data, np.ndarray) and data.dtype == object else None
    if entries is None or not all(isinstance(e, dict) and "qpos" in e for e in entries):
        raise ConfigError(
            f"{path}: not a DexGraspNet grasp file: expected a list of dicts with 'qpos' and "
            "'scale' (grasp_generation/scripts/generate_grasps.py)"
        )
    out = []
    for i, entry in enumerate(entries):
        where = f"{path}[{i}]"
        if not isinstance(entry["qpos"], dict):
            got = type(entry["qpos"]).__name__
            raise ConfigError(f"{where}: qpos is a {got}, expected a dict of joint angles")
        qpos = {
            str(k): float(_numbers(v, where, f"qpos[{k!r}]", "()"))
            for k, v in entry["qpos"].items()
        }
        scale = _numbers(entry.get("scale", 1.0), where, "scale", "()")
        if scale.shape != ():
            raise _shape_error(where, "scale", scale.shape, "() (one number)")
        missing = [k for k in DEXGRASPNET_ROOT if k not in qpos]
        if missing:
            raise ConfigError(f"{where}: no hand root {missing} in its qpos")
        root = [qpos.pop(k) for k in DEXGRASPNET_ROOT]
        oMr = np.eye(4)
        problem = "" if np.isfinite(root).all() else "hand root not finite"
        if not problem and not (np.isfinite(scale) and scale > 0):
            problem = f"object scale {float(scale):g}"
        if not problem:
            oMr[:3, 3] = root[:3]
            oMr[:3, :3] = Rotation.from_euler("xyz", root[3:]).as_matrix()  # static axes, sxyz
        out.append(ForeignGrasp(oMr, qpos, float(scale), where=where, problem=problem))
    return out


def _free_hand(
    row: FloatArray,
    pre: FloatArray | None,
    obj_pose: FloatArray,
    names: list[str],
    scale: float,
    where: str,
) -> ForeignGrasp:
    """A grasp from ``[x, y, z, qw, qx, qy, qz, joints...]`` rows of the free hand in the
    world (the grasp, and the pre-grasp if given), the object at ``obj_pose``
    ``[x, y, z, qw, qx, qy, qz]`` in the world."""
    q = dict(zip(names, row[7:].tolist(), strict=True))
    problem = (
        pose_problem(row[:7], "hand root")
        or pose_problem(obj_pose, "object pose")
        or ("" if pre is None else pose_problem(pre[:7], "pre-grasp hand root"))
        or ("" if np.isfinite(scale) and scale > 0 else f"object scale {scale:g}")
    )
    if problem:
        return ForeignGrasp(np.eye(4), q, scale, where=where, problem=problem)
    oMw = inverse(pose_matrix(obj_pose))
    pre_oMr = pre_q = None
    if pre is not None:
        pre_oMr = oMw @ pose_matrix(pre[:7])
        pre_q = dict(zip(names, pre[7:].tolist(), strict=True))
    return ForeignGrasp(oMw @ pose_matrix(row[:7]), q, scale, pre_oMr, pre_q, where)


def _per_grasp(values: FloatArray, count: int, where: str, field: str) -> FloatArray:
    """Rows of ``values`` (one for all grasps, or one per grasp), one per grasp."""
    if len(values) not in (1, count):
        raise ConfigError(
            f"{where}: {field} has {len(values)} rows for {count} grasps; expected one for all "
            "or one per grasp"
        )
    return np.broadcast_to(values, (count, *values.shape[1:]))


def read_dexonomy(path: Path, joint_names: Sequence[str] | None = None) -> list[ForeignGrasp]:
    """The grasps of a Dexonomy / DexGraspBench file (module docstring)."""
    data = _item(load_npy(path), path, "a Dexonomy grasp dict")
    if "grasp_qpos" not in data or "obj_pose" not in data:
        raise ConfigError(
            f"{path}: not a Dexonomy grasp file: expected the keys 'grasp_qpos' and 'obj_pose' "
            f"(got {sorted(data)})"
        )
    where = str(path)
    grasp = np.atleast_2d(_numbers(data["grasp_qpos"], where, "grasp_qpos"))
    if grasp.ndim != 2 or grasp.shape[1] <= 7:
        raise _shape_error(where, "grasp_qpos", grasp.shape, "(grasps, 7 + joints)")
    pre = data.get("pregrasp_qpos")
    if pre is not None:
        pre = np.atleast_2d(_numbers(pre, where, "pregrasp_qpos"))
        if pre.shape != grasp.shape:
            raise _shape_error(where, "pregrasp_qpos", pre.shape, f"{grasp.shape} as grasp_qpos")
    obj_pose = np.atleast_2d(_numbers(data["obj_pose"], where, "obj_pose"))
    if obj_pose.ndim != 2 or obj_pose.shape[1] != 7:
        raise _shape_error(where, "obj_pose", obj_pose.shape, "(7,) or (grasps, 7)")
    obj_pose = _per_grasp(obj_pose, len(grasp), where, "obj_pose")
    scales = _numbers(data.get("obj_scale", 1.0), where, "obj_scale")
    scales = _per_grasp(np.atleast_1d(scales).ravel(), len(grasp), where, "obj_scale")
    names = _names(joint_names, data.get("joint_names"), grasp.shape[1] - 7, path, "dexonomy")
    return [
        _free_hand(
            row,
            None if pre is None else pre[i],
            obj_pose[i],
            names,
            float(scales[i]),
            f"{path}[{i}]",
        )
        for i, row in enumerate(grasp)
    ]


def read_bodex(path: Path, joint_names: Sequence[str] | None = None) -> list[ForeignGrasp]:
    """The grasps of a BODex file (module docstring)."""
    data = _item(load_npy(path), path, "a BODex grasp dict")
    if "robot_pose" not in data or "obj_pose" not in data:
        raise ConfigError(
            f"{path}: not a BODex grasp file: expected the keys 'robot_pose' and 'obj_pose' (got "
            f"{sorted(data)}); files that name a scene config instead ('scene_path') are not read"
        )
    where = str(path)
    poses = _numbers(data["robot_pose"], where, "robot_pose")
    if poses.ndim == 4:
        poses = poses[0]
    if poses.ndim != 3 or poses.shape[1] < 2 or poses.shape[2] <= 7:
        raise ConfigError(
            f"{path}: robot_pose has shape {np.shape(data['robot_pose'])}, expected (1, B, "
            "stages >= 2, 7 + joints)"
        )
    obj_pose = _numbers(data["obj_pose"], where, "obj_pose")
    if obj_pose.size != 7:
        raise _shape_error(where, "obj_pose", obj_pose.shape, "(1, 7)")
    scale = _numbers(data.get("obj_scale", 1.0), where, "obj_scale").ravel()
    if scale.size != 1:
        raise _shape_error(where, "obj_scale", scale.shape, "(1,)")
    names = _names(joint_names, data.get("joint_names"), poses.shape[2] - 7, path, "bodex")
    return [
        _free_hand(stages[1], stages[0], obj_pose.ravel(), names, float(scale[0]), f"{path}[{i}]")
        for i, stages in enumerate(poses)
    ]


def read_grasps(
    path: str | Path, fmt: str, joint_names: Sequence[str] | None = None
) -> list[ForeignGrasp]:
    """The grasps of one file of format ``fmt`` (:data:`FORMATS`)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"no grasp file {path}; check the path")
    if fmt == "dexgraspnet":
        return read_dexgraspnet(path)
    if fmt == "dexonomy":
        return read_dexonomy(path, joint_names)
    if fmt == "bodex":
        return read_bodex(path, joint_names)
    raise ConfigError(f"unknown grasp format {fmt!r}; known: {', '.join(FORMATS)}")


def _mapped(
    q: Mapping[str, float], hand: HandModel, joint_map: Mapping[str, str], where: str
) -> tuple[dict[str, float], list[str]]:
    """This hand's angles from a file's, and the file's joints this hand has not."""
    renamed = {joint_map.get(name, name): value for name, value in q.items()}
    missing = [name for name in hand.joint_names if name not in renamed]
    if missing:
        raise ConfigError(
            f"{where}: no angle for joints {missing} of {hand.name!r}; the file names "
            f"{sorted(q)}. Map the file's names onto the hand's with --joint-map "
            "their=ours,... (Python: joint_map={...})"
        )
    extra = sorted(name for name in renamed if name not in hand.joint_names)
    return {name: renamed[name] for name in hand.joint_names}, extra


def _outside_limits(hand: HandModel, q: Mapping[str, float]) -> str:
    for name in hand.joint_names:
        if not np.isfinite(q[name]):
            return f"joint {name!r} angle not finite ({q[name]})"
        i = hand.model.joints[hand.model.getJointId(name)].idx_q
        lower, upper = hand.q_lower[i], hand.q_upper[i]
        if not lower - LIMIT_SLACK <= q[name] <= upper + LIMIT_SLACK:
            return f"joint {name!r} outside its limits [{lower:.4g}, {upper:.4g}] rad"
    return ""


def _pregrasp(
    foreign: ForeignGrasp, hand: HandModel, joint_map: Mapping[str, str], rMb: FloatArray
) -> dict[str, Any] | str:
    """A grasp's extra fields (its source, and its pre-grasp where the file has one), or why
    its pre-grasp cannot be used."""
    info: dict[str, Any] = {"source": foreign.where}
    if foreign.pre_oMr is None or foreign.pre_q is None:
        return info
    pre_q = _mapped(foreign.pre_q, hand, joint_map, foreign.where)[0]
    bad = [name for name, value in pre_q.items() if not np.isfinite(value)]
    if bad:
        return f"pre-grasp joint {bad[0]!r} angle not finite"
    info["pregrasp_oMb"] = np.round(foreign.pre_oMr @ rMb, 9).tolist()
    info["pregrasp_q"] = pre_q
    return info


def import_grasps(
    hand: HandModel,
    paths: Sequence[str | Path],
    fmt: str,
    *,
    joint_names: Sequence[str] | None = None,
    joint_map: Mapping[str, str] | None = None,
    root_offset: FloatArray | None = None,
    object_scale: float = 1.0,
    grasp_type: str = "power",
) -> tuple[list[Grasp], dict[str, Any]]:
    """Grasps of ``paths`` (files of format ``fmt``) for ``hand``, and a record of the import
    for the grasp file's ``generator`` field (what was skipped and why).

    Args:
        hand: The hand; every one of its joints must get an angle.
        paths: The files.
        fmt: One of :data:`FORMATS`.
        joint_names: The file's joint order, for formats that do not name their joints.
        joint_map: The file's joint name -> this hand's, where they differ.
        root_offset: (4, 4) ``rMb``, this hand's base frame in the file's hand root; None:
            identity.
        object_scale: The scale of the object mesh the grasps must have been made on.
        grasp_type: The grasp style the grasps are stored as.

    Raises:
        ConfigError: A file cannot be read, a joint of the hand gets no angle, or no grasp of
            the files was made at ``object_scale`` (naming the scales found).
    """
    if not np.isfinite(object_scale) or object_scale <= 0:
        raise ConfigError(f"object_scale {object_scale}: give the scale as a positive number")
    rMb = np.eye(4) if root_offset is None else np.asarray(root_offset, dtype=float)
    if rMb.shape != (4, 4) or not np.isfinite(rMb).all():
        raise ConfigError(f"root_offset: expected a finite (4, 4) pose, got shape {rMb.shape}")
    joint_map = dict(joint_map or {})
    skipped: Counter[str] = Counter()
    ignored: set[str] = set()
    scales: set[float] = set()
    grasps: list[Grasp] = []
    read = 0
    for path in paths:
        for foreign in read_grasps(path, fmt, joint_names):
            read += 1
            if foreign.problem:
                skipped[foreign.problem] += 1
                continue
            scales.add(round(foreign.scale, 9))
            if abs(foreign.scale - object_scale) > SCALE_TOL * max(abs(object_scale), 1.0):
                skipped[f"made on the object at scale {foreign.scale:g}"] += 1
                continue
            q, extra = _mapped(foreign.q, hand, joint_map, foreign.where)
            ignored.update(extra)
            info = _pregrasp(foreign, hand, joint_map, rMb)
            reason = _outside_limits(hand, q) or (info if isinstance(info, str) else "")
            if reason:
                skipped[reason] += 1
                continue
            assert not isinstance(info, str)
            grasps.append(Grasp(len(grasps), foreign.oMr @ rMb, q, grasp_type, extra=info))
    if read and not grasps and skipped and all(r.startswith("made on") for r in skipped):
        raise ConfigError(
            f"none of the {read} grasps was made on the object at scale {object_scale:g}: the "
            f"files hold scales {sorted(scales)}. Give the object at one of them (a mesh "
            "scaled by it) and --object-scale <that scale>"
        )
    record = {
        "method": f"imported from {fmt} files",
        "files": [str(p) for p in paths],
        "read": read,
        "skipped": dict(skipped.most_common()),
        "ignored_joints": sorted(ignored),
        "object_scale": object_scale,
    }
    return grasps, record
