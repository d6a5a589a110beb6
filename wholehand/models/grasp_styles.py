"""A grasp style of ``hand.toml`` (``[grasping]``) as arrays over the hand's joints."""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt

from wholehand.models.hand import HandModel
from wholehand.models.hand_config import GraspStyle

FloatArray = npt.NDArray[np.float64]


def style_arrays(
    hand: HandModel, style: GraspStyle
) -> tuple[FloatArray, FloatArray, npt.NDArray[np.bool_]]:
    """A grasp style's pre-shape q (n_q,) [rad] (other joints 0, clipped to their limits,
    coupled joints set from their leaders), its closing torques (n_v,) [N*m] and which joints
    close (n_v,) bool."""
    q_pre = np.clip(np.zeros(hand.nq), hand.q_lower, hand.q_upper)
    tau_close = np.zeros(hand.nv)
    closing = np.zeros(hand.nv, dtype=bool)
    for name, value in style.preshape.items():
        q_pre[hand.model.joints[hand.model.getJointId(name)].idx_q] = value
    for name, value in style.close_torque.items():
        i = hand.model.joints[hand.model.getJointId(name)].idx_v
        tau_close[i], closing[i] = value, True
    return hand.couple(q_pre), tau_close, closing


CLOSING_SLOPE = 1e-3
"""A joint closes a finger when turning it moves the finger's tip toward the palm by more than
this [m/rad]."""
DERIVED_CLOSE_TORQUE = 0.1
"""Closing torque of a joint in a style derived from the model [N*m] (at most its limit)."""


def with_close_torque(hand: HandModel, style: GraspStyle) -> GraspStyle:
    """``style``, or for a style that names no closing torques (one for the optimiser only)
    the style with those of :func:`derived_close_torque`."""
    if style.close_torque:
        return style
    return dataclasses.replace(style, close_torque=derived_close_torque(hand))


def derived_close_torque(hand: HandModel, step: float = 1e-4) -> dict[str, float]:
    """Closing torques for a hand whose hand.toml gives none, from its model alone: each
    flexion motor (:func:`~wholehand.models.motor_roles.motor_roles`; spread and opposition
    motors, which move the tip sideways or set the thumb, get none) that moves a finger's tip
    (the centroid of its last link's surface samples) toward the palm (the centroid of the
    palm link's samples) at the mid-range configuration closes in that direction with
    :data:`DERIVED_CLOSE_TORQUE` (at most its torque limit). On the shipped hands these are
    the joints their hand.toml names, with the same signs."""
    from wholehand.models.kinematics import HandKinematics
    from wholehand.models.motor_roles import FLEXION, motor_roles

    cfg, s, model = hand.config, hand.samples, hand.model
    kin = HandKinematics(hand)
    tips = [np.flatnonzero(s.link == hand.link_index(links[-1])) for links in cfg.fingers.values()]
    tips = [rows for rows in tips if rows.size]
    palm = np.flatnonzero(s.link == hand.link_index(cfg.palm_link))

    def reach(q: FloatArray) -> float:
        kin.update(hand.couple(q), np.eye(4))
        centre = kin.transform_points(s.p_joint[palm], s.joint[palm]).mean(axis=0)
        points = [kin.transform_points(s.p_joint[r], s.joint[r]).mean(axis=0) for r in tips]
        return float(sum(np.linalg.norm(p - centre) for p in points))

    q0 = hand.neutral()
    roles = motor_roles(hand)
    out: dict[str, float] = {}
    for name in hand.joint_names:
        joint = model.joints[model.getJointId(name)]
        if not hand.actuated_dofs[joint.idx_v] or name in hand.mimics:
            continue
        if name in roles and roles[name].role != FLEXION:
            continue
        plus, minus = q0.copy(), q0.copy()
        plus[joint.idx_q] += step
        minus[joint.idx_q] -= step
        slope = (reach(plus) - reach(minus)) / (2.0 * step)
        if abs(slope) > CLOSING_SLOPE:
            torque = min(DERIVED_CLOSE_TORQUE, float(hand.tau_max[joint.idx_v]))
            out[name] = -float(np.sign(slope)) * torque
    return out
