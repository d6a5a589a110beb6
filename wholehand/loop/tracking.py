"""Tracking lost: an object pose the hand cannot be touching while it regulates a grasp.

A tracker glitch can report the object metres away. Force regulation would then find no
contacts and command zero torque, dropping an object the hand still holds. Instead, a pose
whose object origin lies farther from the palm than any link can reach plus the object's own
size (:class:`ReachBound`) is *tracking lost*: the last torque is held for
:data:`TRACKING_HOLD`, then ramped linearly to zero over :data:`TRACKING_RAMP` (the hardware
guard's stale-pose rule, with its default times); a pose back within reach resumes regulation.
A real jump of the object is accepted as soon as the tracker's poses put it within reach again.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel

FloatArray = npt.NDArray[np.float64]

TRACKING_LOST = "tracking_lost"
"""Status of a regulation cycle whose pose the hand cannot be touching."""
TRACKING_HOLD: float = 0.2
"""How long the last torque is held when tracking is lost [s]."""
TRACKING_RAMP: float = 0.5
"""How long it then takes to ramp to zero [s]."""
REACH_MARGIN: float = 0.1
"""Added to the reach bound [m]: a pose just past the hand's reach is no glitch."""
REACH_DRAWS: int = 16
"""Seeded joint configurations the hand's reach is measured over."""


_REACH: dict[tuple[str, str, int], float] = {}


def hand_reach(hand: HandModel, draws: int = REACH_DRAWS, seed: int = 0) -> float:
    """Farthest any surface sample of the hand lies from the palm frame's origin [m], over the
    neutral configuration and ``draws`` seeded configurations within the joint limits (cached
    per hand: trials build their regulation anew)."""
    key = (hand.name, str(hand.config.path), len(hand.samples))
    if key not in _REACH:
        _REACH[key] = _measure_reach(hand, draws, seed)
    return _REACH[key]


def _measure_reach(hand: HandModel, draws: int, seed: int) -> float:
    kin = HandKinematics(hand)
    rng = np.random.default_rng(seed)
    lower = np.where(np.isfinite(hand.q_lower), hand.q_lower, -np.pi)
    upper = np.where(np.isfinite(hand.q_upper), hand.q_upper, np.pi)
    samples = hand.samples
    farthest = 0.0
    for i in range(draws + 1):
        q = hand.neutral() if i == 0 else rng.uniform(lower, upper)
        if hand.coupled:
            q = hand.couple(q)
        kin.update(q, np.eye(4))
        palm = kin.frame_pose(hand.palm_link)[:3, 3]
        points = kin.transform_points(samples.p_joint, samples.joint)
        farthest = max(farthest, float(np.linalg.norm(points - palm, axis=1).max()))
    return farthest


class ReachBound:
    """Whether an object pose lies within the hand's reach of its palm.

    Args:
        hand: the hand (its samples and joint limits).
        obj: the object (its mesh's extent about its origin).
    """

    def __init__(self, hand: HandModel, obj: ObjectModel) -> None:
        self.palm = hand.palm_link
        extent = float(np.linalg.norm(np.asarray(obj.mesh.vertices), axis=1).max())
        self.radius = hand_reach(hand) + extent + REACH_MARGIN
        """Largest distance from the palm to the object's origin a touching pose can have [m]."""

    def distance(self, kinematics: HandKinematics, wMo: FloatArray) -> float:
        """Distance from the palm (at ``kinematics``) to the object's origin [m]."""
        return float(np.linalg.norm(wMo[:3, 3] - kinematics.frame_pose(self.palm)[:3, 3]))

    def out_of_reach(self, kinematics: HandKinematics, wMo: FloatArray) -> bool:
        """True if the hand cannot be touching an object at ``wMo``."""
        return self.distance(kinematics, wMo) > self.radius


def ramp_scale(held: float) -> float:
    """Share of the last torque applied ``held`` [s] after tracking was lost: 1 for
    :data:`TRACKING_HOLD`, then down to 0 over :data:`TRACKING_RAMP`."""
    return float(np.clip(1.0 - (held - TRACKING_HOLD) / TRACKING_RAMP, 0.0, 1.0))
