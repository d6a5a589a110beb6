"""The safety rules between the stage machine and the arm's position interface.

Every arm target the hardware backend sends passes :meth:`ArmGuard.filter`, which applies, in
this order (the names are the statuses it counts):

1. ``position_limited``: every joint's target within its URDF position limits.
2. ``velocity_limited``: no joint's target moves faster than ``velocity_scale`` times its URDF
   velocity limit from the target sent last; the first target moves from the measured position.
3. ``workspace``: a target that would put the palm outside the workspace's palm box (forward
   kinematics at the target, the hand's joints as measured) is not sent; the target sent last
   is held (before any, the measured position).

:meth:`ArmGuard.hold` gives the measured position as the target (``hold``): the arm stops where
it is, as on a stop request and on every exit of the controller.

Targets are (n_arm,) [rad] in the order of the hand model's arm joints; times on one monotonic
clock [s].
"""

from __future__ import annotations

from collections import Counter

import numpy as np
import numpy.typing as npt

from wholehand.errors import ConfigError
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.reaching.workspace import Box

FloatArray = npt.NDArray[np.float64]


class ArmGuard:
    """Applies the safety rules to each arm target.

    Args:
        hand: the arm-hand assembly.
        velocity_scale: fraction of the URDF velocity limits the targets may move at (0, 1].
        palm_box: the box the palm must stay in (None: no workspace rule).
    """

    def __init__(self, hand: HandModel, velocity_scale: float, palm_box: Box | None) -> None:
        dofs = np.flatnonzero(hand.arm_dofs)
        if not dofs.size:
            raise ConfigError(f"ArmGuard: hand {hand.name!r} has no arm joints")
        if not 0.0 < velocity_scale <= 1.0:
            raise ConfigError(f"ArmGuard: velocity_scale must be in (0, 1], got {velocity_scale}")
        model = hand.model
        self.hand, self.dofs, self.palm_box = hand, dofs, palm_box
        self.q_index = np.array(
            [model.joints[model.getJointId(hand.joint_names[i])].idx_q for i in dofs],
            dtype=np.intp,
        )
        self.lower = hand.q_lower[self.q_index]
        self.upper = hand.q_upper[self.q_index]
        self.max_speed = velocity_scale * np.asarray(model.velocityLimit)[dofs]
        """(n_arm,) largest target speed [rad/s]."""
        if not (np.isfinite(self.max_speed).all() and (self.max_speed > 0.0).all()):
            raise ConfigError(
                f"ArmGuard: the URDF of {hand.name!r} must give every arm joint a velocity limit "
                f"> 0 (<limit velocity=...>), got {self.max_speed / velocity_scale}"
            )
        self.counts: Counter[str] = Counter()
        """Targets per rule that changed them (``ok`` when none did, ``hold`` for holds)."""
        self.last: FloatArray | None = None
        """(n_arm,) the target sent last [rad]; None before the first."""
        self.t_last = 0.0
        self._kin = HandKinematics(hand)
        palm_joint = model.frames[model.getFrameId(hand.palm_link)].parentJoint
        self._palm_chain = np.array(
            [model.joints[j].idx_q for j in model.supports[palm_joint] if j > 0], dtype=np.intp
        )
        """q indices of the joints that move the palm (the arm's, and any hand joint before it)."""
        self._checked: tuple[FloatArray, bool] | None = None  # those joints last checked, inside?

    def filter(self, target: FloatArray, q: FloatArray, now: float) -> tuple[FloatArray, str]:
        """The target to send for the stage's arm ``target`` (n_arm,) [rad] at ``now`` [s], given
        the measured joint positions ``q`` (n_q,); and the rule that decided."""
        status = "ok"
        out = np.minimum(np.maximum(target, self.lower), self.upper)
        if not (out == target).all():
            status = "position_limited"
        if self.last is None:  # the first target is the measured position
            last, step = q[self.q_index], np.zeros_like(self.max_speed)
        else:
            last, step = self.last, self.max_speed * max(now - self.t_last, 0.0)
        limited = np.minimum(np.maximum(out, last - step), last + step)
        if not (limited == out).all():
            status = "velocity_limited"
        if self.palm_box is not None and not self.palm_inside(limited, q):
            return self._sent(last, now, "workspace")
        return self._sent(limited, now, status)

    def palm_inside(self, target: FloatArray, q: FloatArray) -> bool:
        """True if the palm is in the palm box with the arm at ``target`` and the rest of the
        joints at ``q``."""
        assert self.palm_box is not None
        q_target = q.copy()
        q_target[self.q_index] = target
        # Only the joints before the palm move it: a target held (while the hand regulates)
        # is checked once.
        chain = q_target[self._palm_chain]
        if self._checked is not None and np.array_equal(self._checked[0], chain):
            return self._checked[1]
        self._kin.update(q_target, self.hand.wMb)
        inside = self.palm_box.contains(self._kin.frame_pose(self.hand.palm_link)[:3, 3])
        self._checked = (chain, inside)
        return inside

    def hold(self, q: FloatArray, now: float) -> FloatArray:
        """The measured arm position of ``q`` (n_q,) as the target: the arm stops there."""
        return self._sent(q[self.q_index].copy(), now, "hold")[0]

    def _sent(self, target: FloatArray, now: float, status: str) -> tuple[FloatArray, str]:
        self.counts[status] += 1
        self.last = target
        self.t_last = now
        return target, status
