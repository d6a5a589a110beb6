"""The palm frame of a hand, derived from its model: where an object can rest against the palm.

A hand's root frame is wherever its URDF puts it (the Allegro's at the knuckles, the HX5-D20's
at the wrist), so anything that places an object in front of the palm works in this frame
instead:

- x, the palm normal: hand.toml's ``palm_normal`` where it gives one, else the direction the
  tips of the non-thumb fingers move when their closing torques are applied at the pre-shape
  (out of the palm face, toward the grasped object);
- z, the finger direction: from the fingers' first links to their distal links, made normal
  to x;
- y = z x x.

Along those axes the palm link's surface samples give the palm face (largest x), the top of the
palm (largest z, toward the fingers) and the centre of their bounding box.

A claw closes its fingers toward each other, not toward a palm: with its joints at zero the
closing motions of all its tips, the thumb's included, cancel (their sum is less than
:data:`CANCELLING` of their sizes), and its fingers point where the object is. Then x is the
fingers' mean direction (the approach axis), z points from the axis to the first finger's root,
and the object's place is among the fingers instead of in front of a palm: the face is the
plane of the finger roots (largest x among them), the centre their centroid and the top
:data:`CLAW_REACH` past it along z, so that an object placed within 4 cm below the top sits
around the axis.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.errors import ConfigError
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics

FloatArray = npt.NDArray[np.float64]

AXIS_DECIMALS = 9
"""The axes are rounded to this many decimals before they are made orthonormal, so that a frame
aligned with the root frame (up to rounding in the Jacobians) is exactly the root frame, and the
grasps made in it are the same on every platform."""


@dataclass(frozen=True)
class PalmFrame:
    """Palm axes and extents in the hand base frame ``b`` (the URDF root)."""

    bRp: FloatArray
    """(3, 3) columns: palm normal x, across the palm y, finger direction z, base frame."""
    face: float
    """Largest coordinate of the palm surface along x (the palm face) [m]."""
    top: float
    """Largest coordinate of the palm surface along z (where the fingers start) [m]."""
    centre: FloatArray
    """(3,) centre of the palm surface's bounding box along the palm axes [m]."""

    def to_palm(self, p_base: FloatArray) -> FloatArray:
        """Points (..., 3) from base coordinates to coordinates along the palm axes [m]."""
        return np.asarray(p_base) @ self.bRp


CANCELLING = 0.25
"""The fingers' tips close toward each other (a claw) when the sum of their closing velocities
is smaller than this fraction of the sum of their sizes."""
CLAW_ALIGNED_DEG = 30.0
"""A hand whose fingers point within this angle of its palm normal is placed as a claw."""
CLAW_REACH = 0.02
"""A claw's ``top`` lies this far past the centroid of its finger roots [m]."""


def _unit(v: FloatArray) -> FloatArray:
    return cast(FloatArray, v / np.linalg.norm(v))


def closing_direction(
    hand: HandModel,
    kin: HandKinematics,
    tips: FloatArray,
    tip_joint: npt.NDArray[np.intp],
    tau_close: FloatArray,
) -> FloatArray:
    """The summed velocity (3,) of the fingers' tips ``tips`` (F, 3) (on joints ``tip_joint``)
    under the closing torques ``tau_close`` (n_v,), base frame, at ``kin``'s configuration.

    Raises:
        ConfigError: the torques do not move the tips.
    """
    velocities = tip_velocities(hand, kin, tips, tip_joint, tau_close)
    closing = velocities.sum(axis=0)
    if np.linalg.norm(velocities, axis=1).sum() < 1e-9:
        cfg = hand.config
        links = [hand.link_names[i] for i in np.flatnonzero(np.isin(hand.link_joint, tip_joint))]
        raise ConfigError(
            f"{cfg.path}: the closing torques of [grasping] do not move the tips of the fingers "
            f"({links}); give their flexion joints a close_torque, or set palm_normal (the "
            "palm's normal in the hand's root frame) in hand.toml"
        )
    return cast(FloatArray, closing)


def tip_velocities(
    hand: HandModel,
    kin: HandKinematics,
    tips: FloatArray,
    tip_joint: npt.NDArray[np.intp],
    tau_close: FloatArray,
) -> FloatArray:
    """(F, 3) the velocity of each tip under the closing torques taken as joint velocities,
    base frame (the followers of coupled joints moving with their leaders)."""
    if hand.coupled:  # the closing torques drive the actuators, followers move with them
        tau_close = hand.coupling @ (hand.coupling.T @ tau_close)
    return cast(FloatArray, kin.point_jacobians(tip_joint, tips) @ tau_close)


def _non_thumb_fingers(hand: HandModel) -> list[tuple[str, ...]]:
    """The links of every finger but the thumb (``[fingers]``), base to tip.

    Raises:
        ConfigError: there is none.
    """
    cfg = hand.config
    fingers = [tuple(links) for name, links in cfg.fingers.items() if name != cfg.thumb]
    if not fingers:
        raise ConfigError(
            f"{cfg.path}: [fingers] names no finger besides the thumb, so the palm's direction "
            "cannot be found; list each finger's links, base to tip"
        )
    return fingers


def model_palm_normal(hand: HandModel, q: FloatArray, tau_close: FloatArray) -> FloatArray:
    """The palm normal (3,) the model gives, whatever hand.toml says: the unit direction the
    tips of the non-thumb fingers move under ``tau_close`` (n_v,) at ``q`` (n_q,), base frame.

    Raises:
        ConfigError: no finger besides the thumb, or the torques do not move the tips.
    """
    fingers = _non_thumb_fingers(hand)
    kin = HandKinematics(hand)
    kin.update(q, np.eye(4))
    tips = np.array([kin.frame_pose(links[-1])[:3, 3] for links in fingers])
    tip_joint = np.array([hand.link_joint[hand.link_index(links[-1])] for links in fingers])
    closing = closing_direction(hand, kin, tips, tip_joint, tau_close)
    if is_claw(hand, tau_close):  # the fingers, the thumb's too, close toward each other
        every = list(hand.config.fingers.values())
        roots = np.array([kin.frame_pose(links[0])[:3, 3] for links in every])
        tips = np.array([kin.frame_pose(links[-1])[:3, 3] for links in every])
        return _unit(tips.mean(axis=0) - roots.mean(axis=0))
    return _unit(closing)


def is_claw(hand: HandModel, tau_close: FloatArray) -> bool:
    """Whether the tips of all the fingers, the thumb's included, close toward each other with
    the joints at zero (within their limits), as the model lays the fingers out: their closing
    velocities there sum to less than :data:`CANCELLING` of their sizes. (Curled, a claw's
    tips also move back toward its hub together.)"""
    laid_out = pin.neutral(hand.model)
    laid_out = hand.couple(np.clip(laid_out, hand.q_lower, hand.q_upper))
    kin = HandKinematics(hand)
    kin.update(laid_out, np.eye(4))
    links = [links[-1] for links in hand.config.fingers.values()]
    tips = np.array([kin.frame_pose(link)[:3, 3] for link in links])
    joints = np.array([hand.link_joint[hand.link_index(link)] for link in links])
    v = tip_velocities(hand, kin, tips, joints, tau_close)
    return bool(np.linalg.norm(v.sum(axis=0)) < CANCELLING * np.linalg.norm(v, axis=1).sum())


def palm_frame(hand: HandModel, q: FloatArray, tau_close: FloatArray) -> PalmFrame:
    """The palm frame of ``hand`` at the pre-shape ``q`` (n_q,) [rad] with closing torques
    ``tau_close`` (n_v,) [N*m] (the grasp style's; non-closing joints 0).

    Raises:
        ConfigError: the hand names no finger besides the thumb, or the closing torques do not
            move those fingers' tips.
    """
    cfg = hand.config
    fingers = _non_thumb_fingers(hand)
    kin = HandKinematics(hand)
    kin.update(q, np.eye(4))
    roots = np.array([kin.frame_pose(links[0])[:3, 3] for links in fingers])
    tips = np.array([kin.frame_pose(links[-1])[:3, 3] for links in fingers])
    if cfg.palm_normal is not None:  # hand.toml's word over the model's
        closing = np.asarray(cfg.palm_normal, dtype=float)
    else:
        closing = model_palm_normal(hand, q, tau_close)
    normal = _unit(np.round(_unit(closing), AXIS_DECIMALS))
    along = np.round(_unit(tips.mean(axis=0) - roots.mean(axis=0)), AXIS_DECIMALS)
    if along @ normal > np.cos(np.deg2rad(CLAW_ALIGNED_DEG)):  # a claw: among all its fingers
        every = [kin.frame_pose(links[0])[:3, 3] for links in cfg.fingers.values()]
        return _claw_frame(normal, np.array(every), cfg.path)
    along = _unit(along - (along @ normal) * normal)
    bRp = np.column_stack([normal, np.cross(along, normal), along])
    rows = hand.samples.link == hand.link_index(hand.palm_link)
    palm = kin.transform_points(hand.samples.p_joint[rows], hand.samples.joint[rows], np.eye(4))
    p = palm @ bRp
    return PalmFrame(
        bRp=bRp,
        face=float(p[:, 0].max()),
        top=float(p[:, 2].max()),
        centre=0.5 * (p.min(axis=0) + p.max(axis=0)),
    )


def _claw_frame(normal: FloatArray, roots: FloatArray, path: object) -> PalmFrame:
    """The palm frame of a claw (module docstring): the object among the finger roots."""
    centroid = roots.mean(axis=0)
    out = roots[0] - centroid
    out = np.round(out - (out @ normal) * normal, AXIS_DECIMALS)
    if np.linalg.norm(out) < 1e-6:
        raise ConfigError(
            f"{path}: the fingers point along the palm normal from one place; a claw needs its "
            "finger roots apart around the axis, or set palm_normal in hand.toml"
        )
    along = _unit(out)
    bRp = np.column_stack([normal, np.cross(along, normal), along])
    p = roots @ bRp
    centre = centroid @ bRp
    return PalmFrame(bRp=bRp, face=float(p[:, 0].max()), top=float(centre[2] + CLAW_REACH),
                     centre=centre)  # fmt: skip
