"""An arm with a hand on its flange, described by config (``[assembly]`` in hand.toml).

    name = "flexiv_rizon4_allegro_right"
    [assembly]
    arm = "../flexiv_rizon4/rizon4.urdf"     # the arm's URDF, its root fixed in the world
    hand = "allegro_right"                    # a shipped hand or a hand folder
    flange = "flange"                         # the arm link the hand hangs from
    mount = { xyz = [0, 0, 0], rpy = [0, 0, 0] }   # the hand's root link in the flange frame
    arm_gains = { kp = 300.0, kd = 20.0 }     # position servo of every arm joint
    arm_armature = 0.1                        # reflected rotor inertia of each arm joint
    home = [0.0, -0.7, 0.0, 1.57, 0.0, 0.7, 0.0]   # the arm's start posture [rad], URDF order
    [mount]                                   # the arm's root in the world
    xyz = [0, 0, 0]

The two URDFs are merged into one (a fixed joint from the flange to the hand's root, every mesh
URI made absolute) and written to the cache folder under a content hash, so the hand model, the
MuJoCo scene and the viewers load the assembly as they load any hand. Everything about the hand
(palm, fingers, fingertips, torque limits, grasp styles, stored grasps) comes from the hand's
own hand.toml; the arm's moving joints are position-controlled (``HandConfig.arm_joints``), with
the URDF's effort limits, and its links are never contact candidates.

An arm's joints carry the reflected inertia of their motors and gears (``arm_armature``), which a
URDF does not describe. Without it the last wrist joint of the Rizon 4 with a hand on it has
about 0.004 kg*m^2 about its axis, and the servo's damping, applied once per 1 ms simulation step,
overshoots (``kd * dt / I`` = 4.4 > 2): the wrist shakes at several rad/s while the hand holds
an object. The MuJoCo backend refuses a servo whose ``kd * dt / arm_armature`` exceeds 1.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wholehand.errors import AssetError, ConfigError
from wholehand.models.hand_folders import resolve_hand_config
from wholehand.models.mesh_files import resolve_mesh_uri
from wholehand.models.toml_values import three_numbers

ASSEMBLY_KEYS = {"arm", "hand", "flange", "mount", "arm_gains", "arm_armature", "home"}
"""Keys of the ``[assembly]`` table."""
DEFAULT_ARM_GAINS = (300.0, 20.0)
"""Position gain [N*m/rad] and velocity gain [N*m*s/rad] of the arm's joint servo."""
DEFAULT_ARM_ARMATURE = 0.1
"""Reflected rotor inertia of each arm joint [kg*m^2] when ``[assembly]`` does not give one:
the value MuJoCo Menagerie gives the Franka arms' joints (the Rizon 4's is not published)."""


@dataclass(frozen=True)
class Assembly:
    """What ``[assembly]`` says, resolved."""

    arm_urdf: Path
    hand_toml: Path
    flange: str
    mount_xyz: tuple[float, float, float]
    mount_rpy: tuple[float, float, float]
    kp: float
    kd: float
    home: tuple[float, ...] = ()
    """The arm's start posture [rad], its moving joints in URDF order (empty: zeros)."""
    armature: float = DEFAULT_ARM_ARMATURE
    """Reflected rotor inertia of each arm joint [kg*m^2]."""


def parse_assembly(table: Any, where: Path) -> Assembly:
    """Validate an ``[assembly]`` table of the hand.toml at ``where``."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: [assembly] must be a table, got {table!r}")
    unknown = sorted(set(table) - ASSEMBLY_KEYS)
    missing = sorted({"arm", "hand", "flange"} - set(table))
    if unknown or missing:
        raise ConfigError(
            f"{where}: [assembly] "
            + (f"has unknown keys {unknown}" if unknown else f"lacks {missing}")
            + "; its keys are arm, hand, flange (required), mount, arm_gains, arm_armature, home"
        )
    arm = (where.parent / str(table["arm"])).resolve()
    if not arm.is_file():
        raise AssetError(f"{where}: [assembly] arm URDF {arm} does not exist; fix 'arm'")
    hand = table["hand"]
    local = (where.parent / str(hand)).resolve()
    hand_toml = resolve_hand_config(local if local.is_dir() else str(hand))
    mount = table.get("mount", {})
    if not isinstance(mount, dict) or set(mount) - {"xyz", "rpy"}:
        raise ConfigError(f"{where}: [assembly] mount must be {{ xyz = [...], rpy = [...] }}")
    xyz, rpy = (
        three_numbers(mount.get(k, [0.0, 0.0, 0.0]), f"mount.{k}", where, "[assembly]")
        for k in ("xyz", "rpy")
    )
    gains = table.get("arm_gains", {})
    if not isinstance(gains, dict) or set(gains) - {"kp", "kd"}:
        raise ConfigError(f"{where}: [assembly] arm_gains must be {{ kp = ..., kd = ... }}")
    kp = gains.get("kp", DEFAULT_ARM_GAINS[0])
    kd = gains.get("kd", DEFAULT_ARM_GAINS[1])
    for name, value in (("kp", kp), ("kd", kd)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
            raise ConfigError(f"{where}: [assembly] arm_gains.{name} must be > 0, got {value!r}")
    armature = table.get("arm_armature", DEFAULT_ARM_ARMATURE)
    if (
        isinstance(armature, bool)
        or not isinstance(armature, (int, float))
        or not 0.0 < armature < math.inf
    ):
        raise ConfigError(
            f"{where}: [assembly] arm_armature must be a rotor inertia > 0 [kg*m^2], got "
            f"{armature!r}"
        )
    home = table.get("home", [])
    if not isinstance(home, list) or not all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in home
    ):
        raise ConfigError(f"{where}: [assembly] home must be a list of angles [rad], got {home!r}")
    return Assembly(
        arm,
        hand_toml,
        str(table["flange"]),
        xyz,
        rpy,
        float(kp),
        float(kd),
        tuple(float(v) for v in home),
        float(armature),
    )


def _read(path: Path) -> ET.Element:
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as err:
        raise AssetError(f"{path}: not a valid URDF (XML): {err}") from err


def moving_joints(root: ET.Element) -> list[str]:
    """Names of the URDF's moving joints that are not ``<mimic>`` followers, in file order."""
    return [
        j.get("name", "")
        for j in root.iter("joint")
        if j.get("type") not in ("fixed", None) and j.find("mimic") is None
    ]


def root_link(root: ET.Element, where: Path) -> str:
    """The one link that is no joint's child."""
    children = {c.get("link") for j in root.iter("joint") for c in j.iter("child")}
    roots = [link.get("name", "") for link in root.iter("link") if link.get("name") not in children]
    if len(roots) != 1:
        raise AssetError(f"{where}: expected one root link, found {roots}")
    return roots[0]


def _absolute_meshes(root: ET.Element, model_path: Path, package_dirs: tuple[Path, ...]) -> None:
    for mesh in root.iter("mesh"):
        uri = mesh.get("filename", "")
        path = resolve_mesh_uri(uri, model_path, package_dirs)
        if path is None:
            raise AssetError(f"{model_path}: mesh {uri!r} not found")
        mesh.set("filename", str(path.resolve()))


def merged_urdf(
    assembly: Assembly, hand_urdf: Path, hand_packages: tuple[Path, ...], name: str
) -> tuple[str, list[str], list[str]]:
    """The assembly as one URDF string, the hand's URDF ``hand_urdf`` (its meshes found in
    ``hand_packages``) mounted on the arm's flange; the arm's moving joints and the arm's
    links."""
    arm = _read(assembly.arm_urdf)
    hand_root = _read(hand_urdf)
    arm_links = [link.get("name", "") for link in arm.iter("link")]
    if assembly.flange not in arm_links:
        raise ConfigError(
            f"{assembly.hand_toml.parent}: [assembly] flange {assembly.flange!r} is not a link of "
            f"{assembly.arm_urdf.name}; its links are {arm_links}"
        )
    _absolute_meshes(arm, assembly.arm_urdf, (assembly.arm_urdf.parent,))
    _absolute_meshes(hand_root, hand_urdf, hand_packages)
    clash = sorted(set(arm_links) & {link.get("name", "") for link in hand_root.iter("link")})
    if clash:
        raise ConfigError(f"the arm and the hand both have links named {clash}; rename one")
    out = ET.Element("robot", {"name": name})
    for element in list(arm) + list(hand_root):
        if element.tag in ("link", "joint"):
            out.append(element)
    mount = ET.SubElement(out, "joint", {"name": f"{assembly.flange}_to_hand", "type": "fixed"})
    ET.SubElement(mount, "parent", {"link": assembly.flange})
    ET.SubElement(mount, "child", {"link": root_link(hand_root, hand_urdf)})
    ET.SubElement(
        mount,
        "origin",
        {
            "xyz": " ".join(map(repr, assembly.mount_xyz)),
            "rpy": " ".join(map(repr, assembly.mount_rpy)),
        },
    )
    ET.indent(out, space="  ")
    return ET.tostring(out, encoding="unicode"), moving_joints(arm), arm_links


def write_merged(text: str) -> Path:
    """The merged URDF written under its content hash (cache folder, else a temporary one)."""
    from wholehand.models.cache import text_file

    return text_file("assemblies", "assembly", text, "urdf")
