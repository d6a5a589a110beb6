"""Why a URDF does not parse: the mistakes urdfdom refuses, named by joint or link.

Pinocchio's URDF parser (urdfdom) reports only "does not contain a valid URDF model" and prints
its reasons to the console; :func:`urdf_problems` finds the common ones itself so that the error
a user sees names the joint and the fix.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

LIMITED = ("revolute", "prismatic")
"""Joint types urdfdom requires a ``<limit>`` (with ``effort`` and ``velocity``) for."""
JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")


def urdf_problems(path: Path) -> list[str]:
    """What in the URDF at ``path`` urdfdom refuses (empty: nothing found)."""
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as err:
        return [f"not well-formed XML: {err}"]
    if root.tag != "robot":
        return [f"the root element is <{root.tag}>, not <robot>"]
    problems: list[str] = []
    children: set[str] = set()
    for joint in root.findall("joint"):  # not a <transmission>'s <joint>
        problems += _joint_problems(joint, children)
    links = [link.get("name") for link in root.findall("link")]
    roots = [link for link in links if link not in children]
    if len(roots) > 1:
        problems.append(f"links {roots} have no parent joint: a URDF has one root link")
    return problems


def _joint_problems(joint: ET.Element, children: set[str]) -> list[str]:
    """What urdfdom refuses in one ``<joint>``; adds its child link to ``children``."""
    problems = []
    name, kind = joint.get("name", "?"), joint.get("type", "")
    if kind not in JOINT_TYPES:
        problems.append(f"joint {name!r} has type {kind!r}; one of {list(JOINT_TYPES)}")
    for tag in ("parent", "child"):
        element = joint.find(tag)
        link = None if element is None else element.get("link")
        if not link:
            problems.append(f"joint {name!r} has no <{tag} link=...>")
        elif tag == "child":
            children.add(link)
    if kind not in LIMITED:
        return problems
    limit = joint.find("limit")
    if limit is None:
        problems.append(
            f"joint {name!r} ({kind}) has no <limit>; add <limit lower=... upper=... "
            "effort=... velocity=.../>"
        )
    else:
        missing = [a for a in ("effort", "velocity") if limit.get(a) is None]
        if missing:
            problems.append(f"the <limit> of joint {name!r} lacks {missing}")
    return problems
