"""A grasp style of ``hand.toml`` (``[grasping]``) as arrays over the hand's joints."""

from __future__ import annotations

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
