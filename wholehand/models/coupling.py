"""Coupled joints: a follower joint moves with a leader, ``q_f = multiplier * q_l + offset``.

URDF declares a coupling with ``<mimic joint="leader" multiplier="m" offset="o"/>`` on the
follower (a linkage or tendon that one motor drives). The hand model keeps every joint (so the
kinematics are the URDF's), and the controller works in actuator coordinates:

    q = C q_act + d

with ``C`` (n_v, n_a): one column per actuator (a leader, or a joint that nobody follows), 1 on
its own row and the multiplier on each follower's row; ``d`` (n_v,) the offsets. A contact force
``f`` then needs the actuator torques ``C^T J^T f`` (virtual work: ``dq = C dq_act``), the torque
limits are per actuator, and actuation consistency is about the actuated Jacobian ``J C``. A
chain (a follower of a follower) is resolved to its first leader.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from wholehand.errors import ConfigError

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Mimic:
    """One coupling as the URDF declares it."""

    leader: str
    multiplier: float
    offset: float
    """[rad or m]"""


def urdf_mimics(urdf_path: Path) -> dict[str, Mimic]:
    """The ``<mimic>`` couplings of a URDF: follower joint name -> :class:`Mimic`.

    Raises:
        ConfigError: a ``<mimic>`` without a ``joint`` or with a non-numeric multiplier/offset.
    """
    root = ET.parse(urdf_path).getroot()
    out = {}
    for joint in root.iter("joint"):
        mimic = joint.find("mimic")
        if mimic is None:
            continue
        name = joint.get("name", "")
        leader = mimic.get("joint")
        try:
            multiplier = float(mimic.get("multiplier", "1"))
            offset = float(mimic.get("offset", "0"))
        except ValueError as err:
            raise ConfigError(
                f"{urdf_path}: <mimic> of joint {name!r} has a multiplier or offset that is not a "
                f"number ({err})"
            ) from None
        if not leader or not (np.isfinite(multiplier) and np.isfinite(offset)):
            raise ConfigError(
                f'{urdf_path}: <mimic> of joint {name!r} needs joint="LEADER" and finite '
                "multiplier and offset"
            )
        out[name] = Mimic(leader, multiplier, offset)
    return out


def resolve_chains(mimics: dict[str, Mimic], joints: list[str], where: Path) -> dict[str, Mimic]:
    """Every follower coupled directly to a joint that follows nobody (chains composed).

    Raises:
        ConfigError: a leader that is not a moving joint of ``joints``, or a cycle.
    """
    for follower, mimic in mimics.items():
        for name in (follower, mimic.leader):
            if name not in joints:
                raise ConfigError(
                    f"{where}: joint {follower!r} mimics {mimic.leader!r}, but {name!r} is not a "
                    f"moving joint of the hand model; fix the <mimic> tag (joints: {joints})"
                )
    resolved = {}
    for follower in mimics:
        multiplier, offset, leader, seen = 1.0, 0.0, follower, {follower}
        while leader in mimics:
            m = mimics[leader]
            multiplier, offset = multiplier * m.multiplier, multiplier * m.offset + offset
            leader = m.leader
            if leader in seen:
                raise ConfigError(
                    f"{where}: the <mimic> tags of joints {sorted(seen)} form a cycle"
                )
            seen.add(leader)
        resolved[follower] = Mimic(leader, multiplier, offset)
    return resolved


def coupling_matrix(
    joint_names: list[str], idx_v: list[int], actuators: list[str], mimics: dict[str, Mimic]
) -> tuple[FloatArray, FloatArray]:
    """``C`` (n_v, n_a) and ``d`` (n_v,) of ``q = C q_act + d``.

    Args:
        joint_names: the model's moving joints; idx_v: their velocity indices.
        actuators: the actuated joints (no follower among them), in actuator order.
        mimics: resolved couplings (:func:`resolve_chains`); a follower of a joint that is not
            an actuator gets a zero row (it moves with a passive joint).
    """
    n_v = len(joint_names)
    column = {name: a for a, name in enumerate(actuators)}
    index = dict(zip(joint_names, idx_v, strict=True))
    C = np.zeros((n_v, len(actuators)))
    d = np.zeros(n_v)
    for name, a in column.items():
        C[index[name], a] = 1.0
    for follower, m in mimics.items():
        d[index[follower]] = m.offset
        if m.leader in column:
            C[index[follower], column[m.leader]] = m.multiplier
    return C, d
