"""Parsing and validation of ``robots/<name>/hand.toml``.

Schema (all lengths in m, angles in rad, torques in N*m)::

    name = "my_hand"
    urdf = "my_hand.urdf"                      # relative to the hand.toml folder, or
    urdf = { distribution = "pkg", path = "share/.../hand.urdf" }   # inside an installed package
    palm_link = "palm"
    passive_links = ["palm"]                    # default: [palm_link]
    sample_surface = "collision"                # or "visual"
    thumb = "thumb"                             # key of [fingers] that is the thumb
    fingertip_links = ["index_tip", ...]        # distal links
    [fingers]                                   # finger name -> links, base to tip
    index = ["index_1", "index_2", "index_tip"]
    [joints]
    actuated = ["j1", ...]                      # default: every moving joint
    torque_limit = { default = 0.2, j1 = 0.5 }
    [simulation]
    damping = 0.05                              # N*m*s/rad
    armature = 0.001                            # kg*m^2
    [mount]                                     # pose of the root link in the world
    xyz = [0, 0, 0]
    rpy = [0, 0, 0]
    [grasping]                                  # for the grasp generator (power grasps)
    preshape = { j1 = 0.0 }                     # open pose [rad]; others 0, clipped to limits
    close_torque = { j1 = 0.15 }                # closing torque [N*m]; others hold the pre-shape

Names are checked against the URDF when the hand is loaded (:mod:`wholehand.models.hand`).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from wholehand import defaults
from wholehand.errors import AssetError, ConfigError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

SURFACES = ("collision", "visual")


@dataclass(frozen=True)
class HandConfig:
    """The validated content of a hand.toml file."""

    path: Path
    """The hand.toml file."""
    name: str
    urdf_path: Path
    """Resolved URDF file."""
    package_dirs: tuple[Path, ...]
    """Directories searched for ``package://`` mesh URIs."""
    palm_link: str
    passive_links: tuple[str, ...]
    sample_surface: str
    fingers: dict[str, tuple[str, ...]]
    thumb: str | None
    fingertip_links: tuple[str, ...]
    actuated_joints: tuple[str, ...] | None
    """None means every moving joint of the URDF."""
    torque_limit_default: float
    torque_limits: dict[str, float]
    damping: float
    armature: float
    preshape: dict[str, float] = field(default_factory=dict)
    close_torque: dict[str, float] = field(default_factory=dict)
    mount_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mount_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    extra: dict[str, Any] = field(default_factory=dict)


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


def _str_list(table: dict[str, Any], key: str, where: Path, default: list[str] | None = None):
    value = table.get(key, default)
    if value is None:
        return None
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{where}: {key!r} must be a list of names, got {value!r}")
    return tuple(value)


def _number(value: Any, what: str, where: Path, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{where}: {what} must be a number, got {value!r}")
    if positive and not value > 0:
        raise ConfigError(f"{where}: {what} must be > 0, got {value!r}")
    if value < 0:
        raise ConfigError(f"{where}: {what} must be >= 0, got {value!r}")
    return float(value)


def parse_hand_config(path: str | Path) -> HandConfig:
    """Read and validate a hand.toml (syntax, types, file locations; not yet link names)."""
    path = Path(path)
    if path.is_dir():
        path = path / "hand.toml"
    if not path.is_file():
        raise ConfigError(f"hand config {path} does not exist; a hand folder must hold hand.toml")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from err

    known = {
        "name", "urdf", "palm_link", "passive_links", "sample_surface", "thumb",
        "fingertip_links", "fingers", "joints", "simulation", "mount", "grasping",
    }  # fmt: skip
    unknown = sorted(set(raw) - known)
    if unknown:
        raise ConfigError(f"{path}: unknown keys {unknown}; valid keys are {sorted(known)}")
    for key in ("urdf", "palm_link"):
        if key not in raw:
            raise ConfigError(f"{path}: missing required key {key!r}")

    urdf = raw["urdf"]
    if isinstance(urdf, str):
        urdf_path = (path.parent / urdf).resolve()
        if not urdf_path.is_file():
            raise AssetError(f"{path}: URDF {urdf_path} does not exist; fix 'urdf' in hand.toml")
    elif isinstance(urdf, dict) and set(urdf) == {"distribution", "path"}:
        urdf_path = _locate_in_distribution(urdf["distribution"], urdf["path"], path)
    else:
        raise ConfigError(
            f"{path}: 'urdf' must be a path or {{ distribution = ..., path = ... }}, got {urdf!r}"
        )
    # package://name/... URIs resolve against every ancestor of the URDF and the hand folder.
    package_dirs = (path.parent.resolve(), *urdf_path.parents)

    palm = raw["palm_link"]
    surface = raw.get("sample_surface", "collision")
    if surface not in SURFACES:
        raise ConfigError(f"{path}: sample_surface must be one of {SURFACES}, got {surface!r}")

    fingers_raw = raw.get("fingers", {})
    if not isinstance(fingers_raw, dict):
        raise ConfigError(f"{path}: [fingers] must be a table of finger name -> link list")
    fingers = {name: _str_list(fingers_raw, name, path) for name in fingers_raw}
    thumb = raw.get("thumb")
    if thumb is not None and thumb not in fingers:
        raise ConfigError(f"{path}: thumb = {thumb!r} is not a key of [fingers] {sorted(fingers)}")

    sub_keys = {
        "joints": {"actuated", "torque_limit"},
        "simulation": {"damping", "armature"},
        "mount": {"xyz", "rpy"},
        "grasping": {"preshape", "close_torque"},
    }
    for table, allowed in sub_keys.items():
        value = raw.get(table, {})
        if not isinstance(value, dict):
            raise ConfigError(f"{path}: [{table}] must be a table, got {value!r}")
        extra = sorted(set(value) - allowed)
        if extra:
            raise ConfigError(
                f"{path}: unknown keys {extra} in [{table}]; valid keys are {sorted(allowed)}"
            )

    joints = raw.get("joints", {})
    limits_raw = joints.get("torque_limit", {})
    if isinstance(limits_raw, (int, float)):
        limits_raw = {"default": limits_raw}
    default_limit = _number(
        limits_raw.get("default", defaults.TAU_MAX), "torque_limit.default", path, positive=True
    )
    limits = {
        j: _number(v, f"torque_limit.{j}", path, positive=True)
        for j, v in limits_raw.items()
        if j != "default"
    }
    grasping = raw.get("grasping", {})
    preshape, close_torque = {}, {}
    for key, target in (("preshape", preshape), ("close_torque", close_torque)):
        table = grasping.get(key, {})
        if not isinstance(table, dict):
            raise ConfigError(f"{path}: grasping.{key} must be a table of joint name -> number")
        for joint, value in table.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigError(f"{path}: grasping.{key}.{joint} must be a number, got {value!r}")
            target[joint] = float(value)
    sim = raw.get("simulation", {})
    mount = raw.get("mount", {})
    xyz = tuple(float(v) for v in mount.get("xyz", (0.0, 0.0, 0.0)))
    rpy = tuple(float(v) for v in mount.get("rpy", (0.0, 0.0, 0.0)))
    if len(xyz) != 3 or len(rpy) != 3:
        raise ConfigError(f"{path}: [mount] xyz and rpy need 3 numbers each, got {xyz}, {rpy}")

    return HandConfig(
        path=path.resolve(),
        name=str(raw.get("name", path.parent.name)),
        urdf_path=urdf_path,
        package_dirs=package_dirs,
        palm_link=palm,
        passive_links=_str_list(raw, "passive_links", path, [palm]),
        sample_surface=surface,
        fingers=fingers,
        thumb=thumb,
        fingertip_links=_str_list(raw, "fingertip_links", path, []),
        actuated_joints=_str_list(joints, "actuated", path),
        torque_limit_default=default_limit,
        torque_limits=limits,
        damping=_number(sim.get("damping", 0.05), "simulation.damping", path),
        armature=_number(sim.get("armature", 0.001), "simulation.armature", path),
        preshape=preshape,
        close_torque=close_torque,
        mount_xyz=xyz,  # type: ignore[arg-type]
        mount_rpy=rpy,  # type: ignore[arg-type]
    )


def shipped_hands_dir() -> Path:
    """The folder of hands shipped with wholehand (``robots/``)."""
    import wholehand_robots

    return Path(wholehand_robots.__file__).parent


def available_hands() -> list[str]:
    """Names of the shipped hands."""
    return sorted(p.parent.name for p in shipped_hands_dir().glob("*/hand.toml"))


def resolve_hand_config(name_or_path: str | Path) -> Path:
    """Path of a hand.toml from a shipped hand name, a hand folder or a hand.toml path."""
    candidate = Path(name_or_path)
    if candidate.exists():
        return candidate / "hand.toml" if candidate.is_dir() else candidate
    shipped = shipped_hands_dir() / str(name_or_path) / "hand.toml"
    if shipped.is_file():
        return shipped
    raise ConfigError(
        f"no hand named {str(name_or_path)!r}: shipped hands are {available_hands()}; "
        "or pass the path of a folder holding hand.toml"
    )
