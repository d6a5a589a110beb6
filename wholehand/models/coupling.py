"""Coupled joints: a follower joint moves with a leader, ``q_f = multiplier * q_l + offset``.

URDF declares a coupling with ``<mimic joint="leader" multiplier="m" offset="o"/>`` on the
follower (a linkage or tendon that one motor drives), MJCF with a joint equality. The hand model
keeps every joint (so the kinematics are the file's), and the controller works in actuator
coordinates:

    q = C q_act + d

with ``C`` (n_v, n_a): one column per actuator (a leader, or a joint that nobody follows), 1 on
its own row and the multiplier on each follower's row; ``d`` (n_v,) the offsets. A contact force
``f`` then needs the actuator torques ``C^T J^T f`` (virtual work: ``dq = C dq_act``), the torque
limits are per actuator, and actuation consistency is about the actuated Jacobian ``J C``. A
chain (a follower of a follower) is resolved to its first leader.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from wholehand.errors import ConfigError
from wholehand.models.toml_values import joint_numbers

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


def mjcf_mimics(mjcf_path: Path) -> dict[str, Mimic]:
    """The couplings of an MJCF: its joint equalities ``<joint joint1="f" joint2="l"
    polycoef="a0 a1 0 0 0"/>``, i.e. ``q_f - ref_f = a0 + a1 (q_l - ref_l)``, as
    follower -> :class:`Mimic` (``multiplier = a1``, ``offset = a0 + ref_f - a1 ref_l``).

    Raises:
        ConfigError: MuJoCo cannot load the file, an equality fixes a joint alone (lock it in
            hand.toml instead), or a coupling is not linear.
    """
    import mujoco

    try:
        model = mujoco.MjModel.from_xml_path(str(mjcf_path))
    except ValueError as err:
        raise ConfigError(f"{mjcf_path}: MuJoCo cannot load this MJCF: {err}") from err
    out = {}
    for e in range(model.neq):
        if model.eq_type[e] != mujoco.mjtEq.mjEQ_JOINT:
            continue
        follower, leader = int(model.eq_obj1id[e]), int(model.eq_obj2id[e])
        name = model.joint(follower).name
        if leader < 0:
            raise ConfigError(
                f"{mjcf_path}: a joint equality holds joint {name!r} fixed; lock it in hand.toml "
                "([joints] locked) so that the hand model knows it too"
            )
        a0, a1, *higher = (float(c) for c in model.eq_data[e, :5])
        if any(higher):
            raise ConfigError(
                f"{mjcf_path}: the joint equality of {name!r} is not linear (polycoef "
                f"{[a0, a1, *higher]}); only q_f = a0 + a1 q_l couplings are supported"
            )
        ref_f = float(model.qpos0[model.jnt_qposadr[follower]])
        ref_l = float(model.qpos0[model.jnt_qposadr[leader]])
        out[name] = Mimic(model.joint(leader).name, a1, a0 + ref_f - a1 * ref_l)
    return out


def resolve_chains(
    mimics: dict[str, Mimic],
    joints: list[str],
    where: Path,
    sources: dict[str, str] | None = None,
) -> dict[str, Mimic]:
    """Every follower coupled directly to a joint that follows nobody (chains composed).

    Args:
        sources: follower -> where its coupling is declared, for errors (default: a
            ``<mimic>`` tag of ``where``).

    Raises:
        ConfigError: a leader that is not a moving joint of ``joints``, or a cycle (naming
            where each of its couplings is declared).
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
                declared = "; ".join(
                    f"{j}: {(sources or {}).get(j, f'<mimic> in {where.name}')}"
                    for j in sorted(seen)
                )
                raise ConfigError(
                    f"{where}: the couplings of joints {sorted(seen)} form a cycle ({declared}); "
                    "remove one of them"
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


def parse_couplings(table: Any, where: Path) -> dict[str, Mimic]:
    """``[joints] coupled``: follower -> { leader = "j", multiplier = 1.0, offset = 0.0 }."""
    example = 'coupled = { j2 = { leader = "j1", multiplier = 0.8, offset = 0.0 } }'
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: [joints] coupled must be a table, e.g. {example}")
    out = {}
    for follower, spec in table.items():
        what = f"[joints] coupled.{follower}"
        if not isinstance(spec, dict) or not isinstance(spec.get("leader"), str):
            raise ConfigError(f"{where}: {what} must name its leader joint, e.g. {example}")
        unknown = sorted(set(spec) - {"leader", "multiplier", "offset"})
        if unknown:
            raise ConfigError(
                f"{where}: unknown keys {unknown} in {what}; valid keys are leader, multiplier "
                "and offset"
            )
        numbers = joint_numbers(
            {k: spec.get(k, d) for k, d in (("multiplier", 1.0), ("offset", 0.0))}, what, where
        )
        if not all(math.isfinite(v) for v in numbers.values()):
            raise ConfigError(f"{where}: {what}: multiplier and offset must be finite")
        out[follower] = Mimic(spec["leader"], numbers["multiplier"], numbers["offset"])
    return out
