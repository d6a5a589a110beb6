"""Parsing and validation of ``robots/<name>/hand.toml``.

Schema (all lengths in m, angles in rad, torques in N*m)::

    name = "my_hand"
    urdf = "my_hand.urdf"                      # relative to the hand.toml folder, or
    urdf = { distribution = "pkg", path = "share/.../hand.urdf" }   # inside an installed package
    mjcf = "my_hand.xml"                       # instead of urdf: a MuJoCo MJCF file
    root_body = "hand_mount"                   # MJCF only: the hand's body in a scene file
    palm_link = "palm"
    passive_links = ["palm"]                    # default: [palm_link]
    sample_surface = "collision"                # or "visual"
    thumb = "thumb"                             # key of [fingers] that is the thumb
    fingertip_links = ["index_tip", ...]        # distal links
    excluded_links = ["forearm"]                # never contact candidates (still simulated)
    outer_surface_only = false                  # drop samples buried in other collision shapes
    [fingers]                                   # finger name -> links, base to tip
    index = ["index_1", "index_2", "index_tip"]
    [joints]
    actuated = ["j1", ...]                      # default: every moving joint
    locked = { wrist = 0.0 }                    # held at this value [rad or m]: not in the model
    coupled = { j2 = { leader = "j1", multiplier = 0.8, offset = 0.0 } }   # q_j2 = 0.8 q_j1 + 0
    torque_limit = { default = 0.2, j1 = 0.5 }
    [control]
    squeeze = 20.0                              # the allocator's minimum squeeze f_n_min [N]
    [simulation]
    damping = 0.05                              # N*m*s/rad
    armature = 0.001                            # kg*m^2
    [mount]                                     # pose of the root link in the world
    xyz = [0, 0, 0]
    rpy = [0, 0, 0]
    [grasping]                                  # for the grasp generator: power grasps
    preshape = { j1 = 0.0 }                     # open pose [rad]; others 0, clipped to limits
    close_torque = { j1 = 0.15 }                # closing torque [N*m]; others hold the pre-shape
    [grasping.precision]                        # optional, any name: another grasp style
    preshape = { j1 = 0.0 }
    close_torque = { j1 = 0.15 }
    fingers = ["thumb", "index", "middle"]      # keys of [fingers]: exactly these must touch
                                                # (left out: the thumb and two others, palm free
                                                # or not, as for power grasps)
    palm_gap = [0.015, 0.035]                   # object-to-palm gap range at placement [m]

An arm with a hand on its flange is a hand.toml with only ``name``, ``[assembly]`` and ``[mount]``
(:mod:`wholehand.models.assembly`).

Names are checked against the URDF when the hand is loaded (:mod:`wholehand.models.hand`).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from wholehand import defaults
from wholehand.errors import AssetError, ConfigError
from wholehand.models.assembly import merged_urdf, moving_joints, parse_assembly, write_merged
from wholehand.models.coupling import Mimic, parse_couplings
from wholehand.models.toml_values import joint_numbers, number, str_list, three_numbers

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

SURFACES = ("collision", "visual")


POWER_GAP = (0.001, 0.004)
"""Default range of the object-to-palm gap when a power-grasp candidate is placed [m]."""


@dataclass(frozen=True)
class GraspStyle:
    """How the grasp generator closes the hand for one kind of grasp (``[grasping]`` tables)."""

    name: str
    """``power`` or the name of a ``[grasping.<name>]`` sub-table (e.g. ``precision``)."""
    preshape: dict[str, float]
    """Open pose by joint name [rad]; other joints 0, clipped to their limits."""
    close_torque: dict[str, float]
    """Closing torque by joint name [N*m]; other joints hold the pre-shape."""
    fingers: tuple[str, ...] = ()
    """Fingers (keys of ``[fingers]``) that must touch, and the only links besides them that
    may: none. Empty: the thumb and any two other fingers must touch, the palm may."""
    palm_gap: tuple[float, float] = POWER_GAP
    """Range of the gap between the object and the palm face at placement [m]."""


@dataclass(frozen=True)
class HandConfig:
    """The validated content of a hand.toml file."""

    path: Path
    """The hand.toml file."""
    name: str
    model_path: Path
    """Resolved URDF or MJCF file."""
    package_dirs: tuple[Path, ...]
    """Directories searched for ``package://`` mesh URIs."""
    palm_link: str
    passive_links: tuple[str, ...]
    sample_surface: str
    fingers: dict[str, tuple[str, ...]]
    thumb: str | None
    fingertip_links: tuple[str, ...]
    actuated_joints: tuple[str, ...] | None
    """None means every moving joint of the URDF (locked joints excepted)."""
    torque_limit_default: float
    torque_limits: dict[str, float]
    damping: float
    armature: float
    grasp_styles: dict[str, GraspStyle] = field(default_factory=dict)
    """Grasp styles of the grasp generator by name: ``power`` from ``[grasping]``, others from
    its sub-tables (``[grasping.precision]``)."""
    mount_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mount_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    palm_normal: tuple[float, float, float] | None = None
    """The palm's normal (out of the palm face, toward a grasped object) in the hand's root
    frame, where hand.toml gives it; None: derived from how the fingers close
    (:func:`~wholehand.models.palm.palm_frame`)."""
    locked_joints: dict[str, float] = field(default_factory=dict)
    """Joints held at a fixed value [rad or m] (e.g. a wrist): the hand model treats them as
    fixed joints at that value, and the MuJoCo scene welds them there."""
    coupled_joints: dict[str, Mimic] = field(default_factory=dict)
    """Couplings declared in hand.toml (``[joints] coupled``), follower -> leader, for a model
    file without them (a URDF without ``<mimic>`` tags); the model file's own come on top."""
    excluded_links: tuple[str, ...] = ()
    """Links that are never contact candidates (e.g. a forearm); they are still simulated."""
    outer_surface_only: bool = False
    """Drop surface samples buried inside another collision shape of the hand."""
    model_format: str = "urdf"
    """``urdf`` or ``mjcf``: which key of hand.toml named :attr:`model_path`."""
    root_body: str | None = None
    """MJCF only: the body that is the hand's base when the file is a scene with other bodies
    (:mod:`wholehand.models.mjcf_file`); None: the file's one root body."""
    torque_limit_set: bool = False
    """True when hand.toml sets ``[joints] torque_limit`` (False: the paper's default)."""
    arm_joints: tuple[str, ...] = ()
    """An assembly's arm joints (:mod:`wholehand.models.assembly`): position-controlled, with
    the URDF's effort limits; empty for a hand alone."""
    arm_gains: tuple[float, float] = (0.0, 0.0)
    """Position [N*m/rad] and velocity [N*m*s/rad] gains of the arm joints' servo."""
    arm_armature: float = 0.0
    """Reflected rotor inertia of each arm joint [kg*m^2] (simulation)."""
    hand_toml: Path | None = None
    """An assembly's hand alone (its hand.toml): grasps and grasp targets are the hand's."""
    arm_home: tuple[float, ...] = ()
    """An assembly's arm start posture [rad], in the order of :attr:`arm_joints`."""
    squeeze: float | None = None
    """``[control] squeeze``: the least sum of normal forces [N] the allocators keep on this
    hand's grasps (their ``f_n_min``); None: the paper's (:data:`~wholehand.defaults.F_N_MIN`)."""
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def reference(self) -> str:
        """How every command names this hand (``--hand``): a shipped hand's name, else its
        folder's absolute path. The hand.toml's ``name`` need not be either."""
        from wholehand.models.hand_folders import is_shipped_hand

        folder = self.path.resolve().parent
        return folder.name if is_shipped_hand(folder) else str(folder)


def _locate_in_distribution(dist_name: str, rel: str, where: Path) -> Path:
    try:
        dist = metadata.distribution(dist_name)
    except metadata.PackageNotFoundError as err:
        raise AssetError(
            f"{where}: urdf names distribution {dist_name!r}, which is not installed; "
            f"install it with `pip install {dist_name}`"
        ) from err
    rel = rel.strip("/")
    for f in dist.files or []:
        if str(f).replace("\\", "/").endswith(rel):
            path = Path(str(dist.locate_file(f)))
            if path.is_file():
                return path
    raise AssetError(
        f"{where}: no file ending in {rel!r} in installed distribution {dist_name!r} "
        f"{getattr(dist, 'version', '')}; check the path in hand.toml"
    )


HAND_KEYS = frozenset(
    {
        "name",
        "urdf",
        "mjcf",
        "root_body",
        "palm_link",
        "passive_links",
        "sample_surface",
        "thumb",
        "fingertip_links",
        "excluded_links",
        "outer_surface_only",
        "palm_normal",
        "fingers",
        "joints",
        "control",
        "simulation",
        "mount",
        "grasping",
    }
)
"""The top-level keys of a hand's hand.toml."""
SUB_TABLE_KEYS: dict[str, set[str]] = {
    "joints": {"actuated", "locked", "torque_limit", "coupled"},
    "control": {"squeeze"},
    "simulation": {"damping", "armature"},
    "mount": {"xyz", "rpy"},
    "grasping": {"preshape", "close_torque"},
}
"""The keys of hand.toml's tables ([grasping.<name>] sub-tables aside)."""


def _read_hand_toml(path: str | Path) -> tuple[Path, dict[str, Any]]:
    """The hand.toml of ``path`` (the file or its folder) and its parsed contents."""
    path = Path(path)
    if path.is_dir():
        path = path / "hand.toml"
    if not path.is_file():
        raise ConfigError(f"hand config {path} does not exist; a hand folder must hold hand.toml")
    try:
        return path, tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from err


def _check_hand_keys(raw: dict[str, Any], path: Path) -> None:
    """No unknown key, exactly one model file, a palm link."""
    unknown = sorted(set(raw) - HAND_KEYS)
    if unknown:
        raise ConfigError(f"{path}: unknown keys {unknown}; valid keys are {sorted(HAND_KEYS)}")
    if ("urdf" in raw) == ("mjcf" in raw):
        raise ConfigError(
            f'{path}: give the hand\'s model as exactly one of urdf = "hand.urdf" or '
            'mjcf = "hand.xml"'
        )
    if "palm_link" not in raw:
        raise ConfigError(f"{path}: missing required key 'palm_link'")


def _model_source(raw: dict[str, Any], path: Path) -> tuple[str, Path, str | None]:
    """The model's format (``urdf`` or ``mjcf``), its file and an MJCF scene's root body."""
    key = model_format = "urdf" if "urdf" in raw else "mjcf"
    source = raw[key]
    if isinstance(source, str):
        model_path = (path.parent / source).resolve()
        if not model_path.is_file():
            raise AssetError(
                f"{path}: {key.upper()} {model_path} does not exist; fix '{key}' in hand.toml"
            )
    elif isinstance(source, dict) and set(source) == {"distribution", "path"}:
        model_path = _locate_in_distribution(source["distribution"], source["path"], path)
    else:
        raise ConfigError(
            f"{path}: '{key}' must be a path or {{ distribution = ..., path = ... }}, "
            f"got {source!r}"
        )
    root_body = raw.get("root_body")
    if root_body is not None and (model_format != "mjcf" or not isinstance(root_body, str)):
        raise ConfigError(
            f"{path}: root_body names the hand's body in an MJCF scene file (a string, with "
            f"mjcf = ...); got {root_body!r} with {key} = ..."
        )
    return model_format, model_path, root_body


def _fingers(raw: dict[str, Any], path: Path) -> tuple[dict[str, tuple[str, ...]], str | None]:
    """[fingers] (finger name -> links) and the thumb, one of them."""
    fingers_raw = raw.get("fingers", {})
    if not isinstance(fingers_raw, dict):
        raise ConfigError(f"{path}: [fingers] must be a table of finger name -> link list")
    fingers = {name: str_list(fingers_raw, name, path, []) for name in fingers_raw}
    thumb = raw.get("thumb")
    if thumb is not None and thumb not in fingers:
        raise ConfigError(f"{path}: thumb = {thumb!r} is not a key of [fingers] {sorted(fingers)}")
    return fingers, thumb


def _check_sub_tables(raw: dict[str, Any], path: Path) -> None:
    """Every table of :data:`SUB_TABLE_KEYS` is a table with only its keys."""
    for table, allowed in SUB_TABLE_KEYS.items():
        value = raw.get(table, {})
        if not isinstance(value, dict):
            raise ConfigError(f"{path}: [{table}] must be a table, got {value!r}")
        # [grasping.<name>] sub-tables are further grasp styles, checked by _grasp_styles.
        styles = (
            {k for k, v in value.items() if isinstance(v, dict)} if table == "grasping" else set()
        )
        extra = sorted(set(value) - allowed - styles)
        if extra:
            raise ConfigError(
                f"{path}: unknown keys {extra} in [{table}]; valid keys are {sorted(allowed)}"
            )


def parse_hand_config(path: str | Path) -> HandConfig:
    """Read and validate a hand.toml (syntax, types, file locations; not yet link names)."""
    path, raw = _read_hand_toml(path)
    if "assembly" in raw:
        return _assembly_config(raw, path)
    _check_hand_keys(raw, path)
    model_format, model_path, root_body = _model_source(raw, path)
    # package://name/... URIs resolve against every ancestor of the URDF and the hand folder.
    package_dirs = (path.parent.resolve(), *model_path.parents)

    palm = raw["palm_link"]
    surface = raw.get("sample_surface", "collision")
    if surface not in SURFACES:
        raise ConfigError(f"{path}: sample_surface must be one of {SURFACES}, got {surface!r}")
    fingers, thumb = _fingers(raw, path)
    _check_sub_tables(raw, path)

    joints = raw.get("joints", {})
    limits_raw = joints.get("torque_limit", {})
    if isinstance(limits_raw, (int, float)):
        limits_raw = {"default": limits_raw}
    default_limit = number(
        limits_raw.get("default", defaults.TAU_MAX), "torque_limit.default", path, positive=True
    )
    limits = {
        j: number(v, f"torque_limit.{j}", path, positive=True)
        for j, v in limits_raw.items()
        if j != "default"
    }
    grasp_styles = _grasp_styles(raw.get("grasping", {}), fingers, thumb, path)
    locked = joint_numbers(joints.get("locked", {}), "[joints] locked", path)
    coupled = parse_couplings(joints.get("coupled", {}), path)
    outer = raw.get("outer_surface_only", False)
    if not isinstance(outer, bool):
        raise ConfigError(f"{path}: outer_surface_only must be true or false, got {outer!r}")
    sim = raw.get("simulation", {})
    control = raw.get("control", {})
    squeeze = None
    if "squeeze" in control:
        squeeze = number(control["squeeze"], "[control] squeeze (the minimum squeeze [N])", path)
    mount = raw.get("mount", {})
    xyz, rpy = (three_numbers(mount.get(k, [0.0, 0.0, 0.0]), k, path) for k in ("xyz", "rpy"))
    palm_normal = None
    if "palm_normal" in raw:
        palm_normal = three_numbers(raw["palm_normal"], "palm_normal", path, table="top-level")
        if math.hypot(*palm_normal) < 1e-9:
            raise ConfigError(
                f"{path}: palm_normal must be a direction, not zero: the palm's normal in the "
                "hand's root frame, e.g. palm_normal = [1.0, 0.0, 0.0]"
            )

    return HandConfig(
        path=path.resolve(),
        name=str(raw.get("name", path.parent.name)),
        model_path=model_path,
        package_dirs=package_dirs,
        palm_link=palm,
        passive_links=str_list(raw, "passive_links", path, [palm]),
        sample_surface=surface,
        fingers=fingers,
        thumb=thumb,
        fingertip_links=str_list(raw, "fingertip_links", path, []),
        actuated_joints=str_list(joints, "actuated", path),
        locked_joints=locked,
        coupled_joints=coupled,
        excluded_links=str_list(raw, "excluded_links", path, []),
        outer_surface_only=outer,
        torque_limit_set="torque_limit" in joints,
        model_format=model_format,
        root_body=root_body,
        torque_limit_default=default_limit,
        torque_limits=limits,
        damping=number(sim.get("damping", 0.05), "simulation.damping", path),
        armature=number(sim.get("armature", 0.001), "simulation.armature", path),
        grasp_styles=grasp_styles,
        mount_xyz=xyz,
        mount_rpy=rpy,
        palm_normal=palm_normal,
        squeeze=squeeze,
    )


def _grasp_styles(
    grasping: dict[str, Any], fingers: dict[str, tuple[str, ...]], thumb: str | None, path: Path
) -> dict[str, GraspStyle]:
    styles = {
        "power": GraspStyle(
            "power",
            joint_numbers(grasping.get("preshape", {}), "grasping.preshape", path),
            joint_numbers(grasping.get("close_torque", {}), "grasping.close_torque", path),
        )
    }
    for name, table in grasping.items():
        if name in ("preshape", "close_torque"):
            continue
        where = f"grasping.{name}"
        if name == "power":
            raise ConfigError(
                f"{path}: [{where}] is the name of the main style; the power grasp is [grasping] "
                "itself (its preshape and close_torque), so name this style otherwise"
            )
        allowed = {"preshape", "close_torque", "fingers", "palm_gap"}
        if not isinstance(table, dict) or set(table) - allowed:
            extra = sorted(set(table) - allowed) if isinstance(table, dict) else table
            raise ConfigError(
                f"{path}: [{where}] has unknown keys {extra}; valid keys are {sorted(allowed)}"
            )
        style_fingers = str_list(table, "fingers", path, [])
        unknown = [f for f in style_fingers if f not in fingers]
        named = "fingers" in table  # left out: judged as a power grasp
        if unknown or (
            named and (not style_fingers or (thumb is not None and thumb not in style_fingers))
        ):
            raise ConfigError(
                f"{path}: {where}.fingers = {list(style_fingers)} must name the thumb "
                f"{thumb!r} and other keys of [fingers] {sorted(fingers)} (or be left out: the "
                "thumb and two other fingers, as for power grasps)"
            )
        gap = table.get("palm_gap", list(POWER_GAP))
        if (
            not isinstance(gap, list)
            or len(gap) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in gap)
            or not 0.0 <= gap[0] <= gap[1]
        ):
            raise ConfigError(
                f"{path}: {where}.palm_gap must be [low, high] in m with 0 <= low <= high, "
                f"got {gap!r}"
            )
        styles[name] = GraspStyle(
            name,
            joint_numbers(table.get("preshape", {}), f"{where}.preshape", path),
            joint_numbers(table.get("close_torque", {}), f"{where}.close_torque", path),
            style_fingers,
            (float(gap[0]), float(gap[1])),
        )
    return styles


def _assembly_config(raw: dict[str, Any], path: Path) -> HandConfig:
    """The config of an arm-hand assembly: the hand.toml ``raw`` (``name``, ``[assembly]``,
    ``[mount]``) at ``path``, as :func:`~wholehand.models.hand_config.parse_hand_config` returns
    it for an assembly."""
    unknown = sorted(set(raw) - {"name", "assembly", "mount"})
    if unknown:
        raise ConfigError(
            f"{path}: an assembly's hand.toml takes name, [assembly] and [mount]; the hand's own "
            f"settings belong in the hand's hand.toml, not here: {unknown}"
        )
    assembly = parse_assembly(raw["assembly"], path)
    hand = parse_hand_config(assembly.hand_toml)
    if hand.model_format != "urdf" or hand.arm_joints:
        raise ConfigError(f"{path}: [assembly] hand must be a URDF hand, not {hand.path}")
    name = str(raw.get("name", path.parent.name))
    text, arm_joints, arm_links = merged_urdf(assembly, hand.model_path, hand.package_dirs, name)
    if assembly.home and len(assembly.home) != len(arm_joints):
        raise ConfigError(
            f"{path}: [assembly] home has {len(assembly.home)} angles; the arm has "
            f"{len(arm_joints)} moving joints {arm_joints}"
        )
    model_path = write_merged(text)
    actuated = hand.actuated_joints
    if actuated is None:  # "every moving joint" of the hand, not of the arm
        hand_joints = moving_joints(ET.parse(hand.model_path).getroot())
        actuated = tuple(
            j for j in hand_joints if j not in hand.locked_joints and j not in hand.coupled_joints
        )
    mount = raw.get("mount", {})
    if not isinstance(mount, dict) or set(mount) - {"xyz", "rpy"}:
        raise ConfigError(f"{path}: [mount] must be {{ xyz = [...], rpy = [...] }}")
    xyz, rpy = (three_numbers(mount.get(k, [0.0, 0.0, 0.0]), k, path) for k in ("xyz", "rpy"))
    return dataclasses.replace(
        hand,
        path=path.resolve(),
        name=name,
        model_path=model_path,
        package_dirs=(model_path.parent, *hand.package_dirs),
        actuated_joints=actuated,
        excluded_links=(*hand.excluded_links, *arm_links),
        mount_xyz=xyz,
        mount_rpy=rpy,
        arm_joints=tuple(arm_joints),
        arm_gains=(assembly.kp, assembly.kd),
        arm_armature=assembly.armature,
        hand_toml=assembly.hand_toml,
        arm_home=assembly.home or tuple(0.0 for _ in arm_joints),
    )
