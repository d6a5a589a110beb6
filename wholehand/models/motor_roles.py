"""What each motor of a finger does, from the hand's model alone: flexion or spread.

A finger's joints that curl it turn about (nearly) parallel axes, the distal one among them; a
spread (abduction) joint turns about an axis across those, moving the tip sideways rather than
toward the palm. Closing torques derived from the model (:func:`~wholehand.models.grasp_styles.
derived_close_torque`) go to flexion motors only, and ``wholehand hand check`` lists each
motor's role. A joint between the two (a thumb's opposition, say) is ``other``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.models.hand import HandModel

FloatArray = npt.NDArray[np.float64]

FLEXION_COS = float(np.cos(np.radians(30.0)))
"""A joint turning about an axis within 30 deg of the finger's distal axis flexes it."""
SPREAD_COS = float(np.cos(np.radians(60.0)))
"""A joint turning about an axis more than 60 deg from it spreads the finger."""

FLEXION, SPREAD, OTHER = "flexion", "spread", "other"


@dataclass(frozen=True)
class MotorRole:
    """One finger joint's role."""

    joint: str
    finger: str
    role: str
    """:data:`FLEXION`, :data:`SPREAD` or :data:`OTHER`."""
    angle_deg: float
    """Angle between its axis and the finger's distal joint's axis [deg] (0 to 90)."""


def finger_joints(hand: HandModel, links: tuple[str, ...] | list[str]) -> list[int]:
    """Pinocchio ids of the revolute joints that move a finger's tip (its last link) and not
    the palm, base to tip."""
    model = hand.model
    tip = int(hand.link_joint[hand.link_index(links[-1])])
    palm = int(hand.link_joint[hand.link_index(hand.palm_link)])
    palm_support = set(model.supports[palm])
    return [
        int(j)
        for j in model.supports[tip]
        if j > 0 and j not in palm_support and model.joints[j].nv == 1 and _revolute(model, j)
    ]


def _revolute(model: pin.Model, j: int) -> bool:
    return "Prismatic" not in model.joints[j].shortname()


def motor_roles(hand: HandModel) -> dict[str, MotorRole]:
    """The role of every joint of every finger of hand.toml's ``[fingers]``, at the joints'
    mid-range configuration, by joint name."""
    model = hand.model
    data = model.createData()
    finite = np.isfinite(hand.q_lower) & np.isfinite(hand.q_upper)
    q = hand.couple(np.where(finite, 0.5 * (hand.q_lower + hand.q_upper), hand.neutral()))
    pin.computeJointJacobians(model, data, q)
    out: dict[str, MotorRole] = {}
    for finger, links in hand.config.fingers.items():
        joints = finger_joints(hand, links)
        if not joints:
            continue
        axes = {j: _axis(model, data, j) for j in joints}
        distal = axes[joints[-1]]
        for j in joints:
            cos = min(1.0, abs(float(axes[j] @ distal)))
            role = FLEXION if cos >= FLEXION_COS else SPREAD if cos <= SPREAD_COS else OTHER
            name = model.names[j]
            out[name] = MotorRole(name, finger, role, float(np.degrees(np.arccos(cos))))
    return out


def _axis(model: pin.Model, data: pin.Data, j: int) -> FloatArray:
    """Joint ``j``'s rotation axis in the base frame (unit), from its Jacobian column."""
    column = pin.getJointJacobian(model, data, j, pin.ReferenceFrame.WORLD)[
        3:, model.joints[j].idx_v
    ]
    return np.asarray(column / np.linalg.norm(column))
