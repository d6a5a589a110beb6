"""The ``home`` stage of a robot's stage machine: the arm returns to its home posture while the
object is out of its workspace, and reaching resumes once it is back (paper Sec. V-D).

    reach_pregrasp / reach_grasp --(object outside the workspace's object box)--> home
    home --(object inside the box, with a fresh pose, for HOME_DWELL)--> reach_pregrasp

The reference moves from where the joints were on entering toward the home posture at
:data:`HOME_SPEED` at most per joint, so the arm goes home smoothly on any backend; the fingers
open to the grasp style's pre-shape on the way.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from wholehand.backends.command import Command, JointTargets
from wholehand.errors import ConfigError
from wholehand.loop.stage import CycleContext, Stage, StageOutput
from wholehand.models.gravity import GravityCompensation
from wholehand.models.hand import HandModel
from wholehand.reaching.stages import FINGER_KD, FINGER_KP, HOME, PREGRASP, ArmServo
from wholehand.reaching.workspace import Workspace

FloatArray = npt.NDArray[np.float64]

HOME_SPEED: float = 0.5
"""Largest speed of the home stage's reference per joint [rad/s]."""
HOME_DWELL: float = 0.5
"""How long the object must be back in the workspace, with fresh poses, before reaching
resumes [s]."""


class HomeStage(Stage):
    """Servo an assembly's arm to its home posture and the fingers to their pre-shape.

    Args:
        hand: the arm-hand assembly.
        q_home: (n_q,) the home configuration: arm joints at home, fingers at the pre-shape.
        workspace: its object box says when the object is back.
        pose_timeout: a pose older than this [s] does not count as the object being back.
        gravity_compensation: the fingers' servo adds their links' gravity torques.

    Status: ``home``.
    """

    name = HOME
    needs_object_pose = False

    def __init__(
        self,
        hand: HandModel,
        q_home: FloatArray,
        workspace: Workspace,
        pose_timeout: float,
        gravity_compensation: bool = False,
    ) -> None:
        if not hand.arm_dofs.any():
            raise ConfigError(f"HomeStage: hand {hand.name!r} has no arm to send home")
        q_home = np.asarray(q_home, dtype=float)
        if q_home.shape != (hand.nq,) or not np.isfinite(q_home).all():
            raise ConfigError(f"HomeStage: q_home must be ({hand.nq},) finite values [rad]")
        self.hand, self.q_home, self.workspace = hand, q_home, workspace
        self.pose_timeout = pose_timeout
        self.arm = ArmServo(hand)
        self.gravity = GravityCompensation(hand) if gravity_compensation else None
        kp, kd = np.full(hand.nv, FINGER_KP), np.full(hand.nv, FINGER_KD)
        kp[self.arm.dofs], kd[self.arm.dofs] = self.arm.kp, self.arm.kd
        self._kp, self._kd = kp, kd
        self._dofs = np.arange(hand.nv)
        self._q_ref = q_home.copy()
        self._back_since: float | None = None

    def start(self, context: CycleContext) -> None:
        self._q_ref = context.obs.q.copy()
        self._back_since = None

    def object_back(self, context: CycleContext) -> bool:
        """True if a fresh pose puts the object inside the workspace's object box."""
        obs = context.obs
        if obs.wMo is None or obs.stamp_q - obs.stamp_object > self.pose_timeout:
            return False
        return self.workspace.object.contains(obs.wMo[:3, 3])

    def step(self, context: CycleContext) -> StageOutput:
        obs = context.obs
        step = HOME_SPEED * context.dt
        self._q_ref = self._q_ref + np.clip(self.q_home - self._q_ref, -step, step)
        tau = np.zeros(self.hand.nv)
        if self.gravity is not None:
            tau = self.hand.joint_torques(self.gravity.actuation_torques(obs.q, obs.wMb))
        tau[self.arm.dofs] = self.arm.feedforward(obs.q, obs.wMb)
        servo = JointTargets(self._dofs, self._q_ref, None, self._kp, self._kd, name="joints")
        command = Command(tau, (servo,))
        if not self.object_back(context):
            self._back_since = None
            return StageOutput(command, "home")
        if self._back_since is None:
            self._back_since = context.t
        if context.t - self._back_since >= HOME_DWELL:
            reason = f"the object is back in the workspace for {HOME_DWELL} s"
            return StageOutput(command, "home", next=PREGRASP, reason=reason)
        return StageOutput(command, "home")
