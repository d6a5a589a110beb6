"""A small hand with known geometry, written as a user would write one (URDF + hand.toml).

In the palm link's frame: the palm is a box whose face is the plane x = 0 (x points out of the
palm) and whose top edge is z = 0; two fingers of two links each start on that edge at
y = +-0.025 and point along +z, their joints turning about +y (positive angles close them
toward +x); a one-link thumb sticks out along +x at z = -0.07 and closes toward +z (axis -y).
The palm hangs from a root link through a fixed joint (``palm_xyz``, ``palm_rpy``), or through a
revolute wrist joint about the root's x axis (``wrist=True``); ``forearm=True`` adds a large box
below the palm on the root; ``knuckle=True`` a second palm box buried inside the first;
``spread=True`` a spread (abduction) joint ``f1_j0`` about the palm normal at the index's root;
``side_thumb=True`` puts the thumb at the palm's side instead (its root at y = -0.045, z = -0.04,
pointing along +x), turning about +z, so that it closes across the palm face toward +y.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

INERTIAL = """<inertial><mass value="{m}"/>
      <inertia ixx="{i}" iyy="{i}" izz="{i}" ixy="0" ixz="0" iyz="0"/></inertial>"""


def _box(size: tuple[float, ...], xyz: tuple[float, ...]) -> str:
    return (
        f'<collision><origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}"/>'
        f'<geometry><box size="{size[0]} {size[1]} {size[2]}"/></geometry></collision>'
    )


def _link(
    name: str,
    size: tuple[float, float, float] | None,
    xyz: tuple[float, ...] = (0, 0, 0),
    mass: float = 0.02,
    extra: str = "",
) -> str:
    geometry = ("" if size is None else _box(size, xyz)) + extra
    return f'<link name="{name}">{geometry}{INERTIAL.format(m=mass, i=mass * 1e-4)}</link>\n'


def _joint(
    name: str,
    parent: str,
    child: str,
    xyz: tuple[float, ...],
    axis: str = "0 1 0",
    kind: str = "revolute",
    rpy: tuple[float, ...] = (0, 0, 0),
    lower: float = -0.2,
    upper: float = 1.6,
    inner: str = "",
) -> str:
    limit = (
        ""
        if kind == "fixed"
        else (
            f'<axis xyz="{axis}"/><limit lower="{lower}" upper="{upper}" effort="1" velocity="5"/>'
        )
    )
    return (
        f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}" rpy="{rpy[0]} {rpy[1]} {rpy[2]}"/>'
        f"{limit}{inner}</joint>\n"
    )


KNUCKLE = ((0.01, 0.06, 0.02), (-0.01, 0.0, -0.04))
"""Size and centre of the ``knuckle=True`` box, palm frame [m]: 5 mm or more inside the palm."""


MIMIC = (0.8, 0.1)
"""``mimic=True``: each finger's second joint follows its first, ``q2 = 0.8 q1 + 0.1`` [rad]."""


def toy_urdf(
    palm_xyz=(0.0, 0.0, 0.0),
    palm_rpy=(0.0, 0.0, 0.0),
    wrist=False,
    forearm=False,
    knuckle=False,
    mimic=False,
    spread=False,
    side_thumb=False,
):
    body = _link("root", None, mass=0.1)
    if wrist:
        body += _joint("wrist", "root", "palm", palm_xyz, "1 0 0", rpy=palm_rpy, lower=-1, upper=1)
    else:
        body += _joint("root_to_palm", "root", "palm", palm_xyz, kind="fixed", rpy=palm_rpy)
    body += _link(
        "palm", (0.02, 0.08, 0.08), (-0.01, 0.0, -0.04), 0.1, _box(*KNUCKLE) if knuckle else ""
    )
    if forearm:
        body += _joint("root_to_forearm", "root", "forearm", (-0.01, 0, -0.14), kind="fixed")
        body += _link("forearm", (0.04, 0.06, 0.12), mass=0.3)
    for k, y in (("1", 0.025), ("2", -0.025)):
        if spread and k == "1":  # a spread motor at the index's root, about the palm normal
            body += _joint(
                "f1_j0", "palm", "f1_0", (0.0, y, 0.0), axis="1 0 0", lower=-0.3, upper=0.3
            )
            body += _link("f1_0", None, mass=0.005)
            body += _joint("f1_j1", "f1_0", "f1_1", (0.0, 0.0, 0.0))
        else:
            body += _joint(f"f{k}_j1", "palm", f"f{k}_1", (0.0, y, 0.0))
        body += _link(f"f{k}_1", (0.015, 0.015, 0.04), (0.0, 0.0, 0.02))
        tag = f'<mimic joint="f{k}_j1" multiplier="{MIMIC[0]}" offset="{MIMIC[1]}"/>'
        body += _joint(f"f{k}_j2", f"f{k}_1", f"f{k}_2", (0.0, 0.0, 0.04), inner=tag * mimic)
        body += _link(f"f{k}_2", (0.015, 0.015, 0.03), (0.0, 0.0, 0.015))
    if side_thumb:
        body += _joint("t_j1", "palm", "t_1", (0.0, -0.045, -0.04), axis="0 0 1")
    else:
        body += _joint("t_j1", "palm", "t_1", (0.0, 0.0, -0.07), axis="0 -1 0")
    body += _link("t_1", (0.06, 0.015, 0.015), (0.03, 0.0, 0.0))
    return f'<?xml version="1.0"?>\n<robot name="toy">\n{body}</robot>\n'


def _mjcf_body(
    name: str,
    size: tuple[float, ...],
    centre: tuple[float, ...],
    pos: tuple[float, ...],
    joint: str,
    axis: str,
    inner: str = "",
    mass: float = 0.02,
) -> str:
    half = " ".join(f"{0.5 * v:g}" for v in size)
    return (
        f'<body name="{name}" pos="{pos[0]} {pos[1]} {pos[2]}">'
        f'<joint name="{joint}" axis="{axis}" range="-0.2 1.6"/>'
        f'<inertial pos="0 0 0" mass="{mass}" diaginertia="{mass * 1e-4} {mass * 1e-4} '
        f'{mass * 1e-4}"/>'
        f'<geom type="box" size="{half}" pos="{centre[0]} {centre[1]} {centre[2]}"/>{inner}</body>'
    )


def toy_mjcf(palm_xyz=(0.0, 0.0, 0.0), palm_rpy=(0.0, 0.0, 0.0), mimic=False):
    """The same hand as :func:`toy_urdf` in MJCF (no wrist, forearm or knuckle): the palm body
    posed by extrinsic x-y-z Euler angles (the URDF's rpy), a floor, a visual-only sphere on the
    palm, position actuators and a keyframe, all of which the scene must drop; with ``mimic``
    the couplings as joint equalities."""
    fingers = ""
    for k, y in (("1", 0.025), ("2", -0.025)):
        tip = _mjcf_body(
            f"f{k}_2", (0.015, 0.015, 0.03), (0, 0, 0.015), (0, 0, 0.04), f"f{k}_j2", "0 1 0"
        )
        fingers += _mjcf_body(
            f"f{k}_1", (0.015, 0.015, 0.04), (0, 0, 0.02), (0, y, 0), f"f{k}_j1", "0 1 0", tip
        )
    thumb = _mjcf_body("t_1", (0.06, 0.015, 0.015), (0.03, 0, 0), (0, 0, -0.07), "t_j1", "0 -1 0")
    x, r = palm_xyz, palm_rpy
    equality = "".join(
        f'<joint joint1="f{k}_j2" joint2="f{k}_j1" polycoef="{MIMIC[1]} {MIMIC[0]} 0 0 0"/>'
        for k in "12"
    )
    return f"""<mujoco model="toy">
  <compiler angle="radian" eulerseq="XYZ"/>
  <worldbody>
    <light pos="0 0 1"/>
    <geom name="floor" type="plane" size="1 1 0.1" pos="0 0 -0.5"/>
    <body name="palm" pos="{x[0]} {x[1]} {x[2]}" euler="{r[0]} {r[1]} {r[2]}">
      <inertial pos="0 0 0" mass="0.1" diaginertia="1e-5 1e-5 1e-5"/>
      <geom type="box" size="0.01 0.04 0.04" pos="-0.01 0 -0.04"/>
      <geom name="palm_visual" type="sphere" size="0.03" contype="0" conaffinity="0"/>
      {fingers}{thumb}
    </body>
  </worldbody>
  <equality>{equality if mimic else ""}</equality>
  <actuator><position joint="f1_j1" kp="1"/><position joint="t_j1" kp="1"/></actuator>
  <keyframe><key qpos="0 0 0 0 0"/></keyframe>
</mujoco>
"""


TOML = """\
name = "toy"
{model}
palm_link = "palm"
thumb = "thumb"
fingertip_links = ["f1_2", "f2_2", "t_1"]
{top}
[fingers]
index = ["f1_1", "f1_2"]
middle = ["f2_1", "f2_2"]
thumb = ["t_1"]

[grasping]
close_torque = {{ {close} }}
{tables}
"""


def write_toy_hand(
    folder: Path, top: str = "", tables: str = "", mjcf: bool = False, **urdf: object
) -> Path:
    """Write ``toy.urdf`` (or ``toy.xml`` with ``mjcf``) and ``hand.toml`` into ``folder`` (made
    if needed); return it.

    ``top`` adds top-level keys to hand.toml, ``tables`` adds tables at its end; ``urdf``
    keywords go to :func:`toy_urdf` (or :func:`toy_mjcf`), except ``toml_coupling=True``: the
    couplings of ``mimic=True`` declared in hand.toml's ``[joints] coupled`` instead.
    """
    if urdf.pop("toml_coupling", False):
        m, offset = MIMIC
        tables += (
            "\n[joints]\ncoupled = { "
            + ", ".join(
                f'f{k}_j2 = {{ leader = "f{k}_j1", multiplier = {m}, offset = {offset} }}'
                for k in "12"
            )
            + " }\n"
        )
        urdf["coupled_close"] = True
    coupled_close = urdf.pop("coupled_close", False) or urdf.get("mimic")
    folder.mkdir(parents=True, exist_ok=True)
    if mjcf:
        (folder / "toy.xml").write_text(toy_mjcf(**urdf))  # type: ignore[arg-type]
    else:
        (folder / "toy.urdf").write_text(toy_urdf(**urdf))  # type: ignore[arg-type]
    model = 'mjcf = "toy.xml"' if mjcf else 'urdf = "toy.urdf"'
    close = "f1_j1 = 0.1, f2_j1 = 0.1, t_j1 = 0.1"
    if not coupled_close:  # the second joints close too when they have motors of their own
        close += ", f1_j2 = 0.05, f2_j2 = 0.05"
    (folder / "hand.toml").write_text(
        TOML.format(
            model=model, top=textwrap.dedent(top), tables=textwrap.dedent(tables), close=close
        )
    )
    return folder


CLAW_RADIUS = 0.03
"""Distance of the claw's finger roots from its axis [m]."""


def claw_urdf() -> str:
    """A three-fingered claw with no palm surface: a small hub block behind the finger roots
    (z < -0.01, where no object reaches), three
    fingers of two links each, their roots at :data:`CLAW_RADIUS` from the z axis at 0, 120 and
    240 deg, pointing along +z; each joint turns about the tangent so that positive angles close
    the finger toward the axis. The object sits on +z between the fingers."""
    import math

    body = _link("root", None, mass=0.1)
    body += _joint("root_to_hub", "root", "hub", (0.0, 0.0, 0.0), kind="fixed")
    body += _link("hub", (0.02, 0.02, 0.02), (0.0, 0.0, -0.02), mass=0.05)
    for k in range(3):
        a = 2.0 * math.pi * k / 3.0
        root = (CLAW_RADIUS * math.cos(a), CLAW_RADIUS * math.sin(a), 0.0)
        axis = f"{math.sin(a):.9f} {-math.cos(a):.9f} 0"  # minus the tangent: closes inward
        body += _joint(f"c{k}_j1", "hub", f"c{k}_1", root, axis=axis, lower=-0.3, upper=1.4)
        body += _link(f"c{k}_1", (0.015, 0.015, 0.05), (0.0, 0.0, 0.025))
        body += _joint(f"c{k}_j2", f"c{k}_1", f"c{k}_2", (0.0, 0.0, 0.05), axis=axis, upper=1.4)
        body += _link(f"c{k}_2", (0.015, 0.015, 0.04), (0.0, 0.0, 0.02))
    return f'<?xml version="1.0"?>\n<robot name="claw">\n{body}</robot>\n'


CLAW_TOML = """\
name = "claw"
urdf = "claw.urdf"
palm_link = "hub"
fingertip_links = ["c0_2", "c1_2", "c2_2"]

[joints]
torque_limit = { default = 0.5 }

[fingers]
a = ["c0_1", "c0_2"]
b = ["c1_1", "c1_2"]
c = ["c2_1", "c2_2"]
"""


def write_claw_hand(folder: Path) -> Path:
    """Write the claw of :func:`claw_urdf` and a hand.toml with no [grasping] table (the
    closing directions and the palm come from the model) into ``folder``; return it."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "claw.urdf").write_text(claw_urdf())
    (folder / "hand.toml").write_text(CLAW_TOML)
    return folder
