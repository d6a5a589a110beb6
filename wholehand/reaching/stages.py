"""The stage machine of the autonomous pipeline (paper Sec. III-D).

    reach_pregrasp --(mean fingertip error < 2 cm)--> reach_grasp
    reach_grasp --(thumb and two other fingers touch, by the geometric estimate)--> regulate
    reach_grasp --(no such touch within GRASP_TIMEOUT)--> reach_pregrasp (another grasp)
    reach_pregrasp --(pre-grasp not reached within PREGRASP_TIMEOUT)--> another grasp
    regulate --(hull of fingertips and palm leaves the object's bounding box)--> reach_pregrasp

On a robot, with a :class:`~wholehand.reaching.workspace.Workspace`, two more rules (paper Sec.
V-D): the palm's targets are kept in the workspace's palm box, and an object outside its object
box sends the reaching stages to ``home`` (:mod:`wholehand.reaching.home`), which returns once the
object is back. With a ``pose_timeout``, a reaching stage whose object pose has grown older than
it holds the arm and fingers where they are (status ``pose_lost``) until a fresh pose arrives.

Every target follows the tracked object pose, so the hand reacts to the object moving before
contact. On entering ``reach_pregrasp`` the plan (a stored grasp and its pre-grasp,
:mod:`wholehand.reaching.pregrasp`) whose pre-grasp is nearest the current palm is chosen
among those usable at the object's current pose.

Reaching commands a floating wrist (``Command.base``) or an assembly's arm joints, and the finger
joints, as position targets that the backend's servo tracks within the torque limits (the arm
with gravity feed-forward, :class:`ArmServo`; the fingers with it on request). Force regulation
commands the hand's torques and leaves the wrist where it is (an arm holds the posture it
grasped at).
"""

from __future__ import annotations

import dataclasses
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand import defaults
from wholehand.backends.command import Command, JointTargets
from wholehand.backends.observation import Observation
from wholehand.contacts.base import ContactEstimator
from wholehand.errors import ConfigError
from wholehand.loop.grasp_loss import GraspLossCheck
from wholehand.loop.regulation import ForceRegulation
from wholehand.loop.stage import CycleContext, Stage, StageOutput
from wholehand.loop.tracking import TRACKING_HOLD, TRACKING_RAMP
from wholehand.models.gravity import GravityCompensation
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.reaching.base import Reacher, ReachTargets
from wholehand.reaching.pregrasp import GraspPlan, nearest_plan
from wholehand.reaching.workspace import Workspace

FloatArray = npt.NDArray[np.float64]

PREGRASP, GRASP, REGULATE, HOME = "reach_pregrasp", "reach_grasp", "regulate", "home"
"""Stage names (``home`` on a robot only: :mod:`wholehand.reaching.home`)."""

TOUCH_DISTANCE: float = 0.002
"""A finger touches the object when a sample of it is within this signed distance [m]."""
GRASP_TIMEOUT: float = 3.0
"""Longest time in ``reach_grasp`` without the touch that hands over to regulation [s]."""
PREGRASP_TIMEOUT: float = 4.0
"""Longest time in ``reach_pregrasp`` before another plan is chosen [s]."""
FINGER_KP: float = 2.0
"""Position gain of the finger servo while reaching [N*m/rad] (torques stay within limits)."""
FINGER_KD: float = 0.05
"""Velocity gain of the finger servo while reaching [N*m*s/rad]."""
SQUEEZE: float = 0.2
"""At the grasp stage, how far past the grasp the finger servo closes the closing joints [rad],
so the fingers press on the object instead of stopping a millimetre short (a stored grasp's
angles are those of a settled grasp, within 0-3 mm of the surface in the estimate)."""
SQUEEZE_PALM_ERROR: float = 0.01
"""The squeeze starts once the palm is within this distance of its grasp pose [m]."""
TIMES_KEPT = 100_000
"""Reacher step times kept (the latest), for benchmarks."""
MAX_WRIST_LEAD: float = 0.02
"""Farthest a floating wrist's reference may run ahead of the measured wrist [m]."""
MAX_LEAD: float = 0.3
"""Farthest the finger reference may run ahead of the measured joint angles [rad]."""


@dataclass
class ReachPlanner:
    """Holds the plans usable at an object pose and the one chosen (shared by the stages).

    Args:
        plans: every grasp's plan.
        usable: plan, object pose -> whether the plan can be used there (e.g. above the table).
    """

    plans: list[GraspPlan]
    usable: Callable[[GraspPlan, FloatArray], bool]
    chosen: GraspPlan | None = None
    failed: set[tuple[str, int]] = field(default_factory=set)
    """(style, grasp id) of the plans whose pre-grasp or grasp timed out; skipped until every
    usable one has."""

    def choose(self, wMo: FloatArray, wMb_now: FloatArray) -> GraspPlan | None:
        """Choose the usable plan nearest the current base pose, preferring those that have not
        failed; None if none is usable."""
        plans = [p for p in self.plans if self.usable(p, wMo)]
        fresh = [p for p in plans if (p.style, p.grasp_id) not in self.failed]
        if plans and not fresh:
            self.failed.clear()
            fresh = plans
        self.chosen = nearest_plan(fresh, wMo, wMb_now) if fresh else None
        return self.chosen

    def fail(self) -> None:
        """The chosen plan did not work: skip it at the next choice."""
        if self.chosen is not None:
            self.failed.add((self.chosen.style, self.chosen.grasp_id))


def _targets(
    kin: HandKinematics, q: FloatArray, wMb: FloatArray, links: list[str]
) -> dict[str, FloatArray]:
    kin.update(q, wMb)
    return {link: kin.frame_pose(link) for link in links}


def root_link(hand: HandModel) -> str:
    """Name of the hand's root link (the frame its stored grasps place, ``oMb``)."""
    model = hand.model
    return str(
        next(f.name for f in model.frames if f.parentJoint == 0 and f.type == pin.FrameType.BODY)
    )


class ArmServo:
    """The position servo of an assembly's arm joints, with gravity feed-forward.

    Commands ``tau = g(q)`` on the arm joints plus the backend's PD law toward the targets
    (gains from ``[assembly] arm_gains``); the hand's own joints are left to the caller.
    """

    def __init__(self, hand: HandModel) -> None:
        self.dofs = np.flatnonzero(hand.arm_dofs)
        self.kp, self.kd = hand.config.arm_gains
        self.gravity = GravityCompensation(hand)

    def feedforward(self, q: FloatArray, wMb: FloatArray) -> FloatArray:
        """(n_arm,) gravity torques of the arm joints [N*m] at ``q``."""
        return self.gravity.torques(q, wMb)[self.dofs]


class ReachStage(Stage):
    """Drive the hand toward the chosen plan's pre-grasp (``kind="pregrasp"``) or grasp.

    ``gravity_compensation``: the finger servo adds the links' gravity torques
    (:class:`~wholehand.models.gravity.GravityCompensation`) to its PD law.

    Status: ``reaching``, or ``no_plan`` when no stored grasp is usable at the object's pose
    (the hand then holds still and the choice is retried every cycle); with ``workspace``,
    ``out_of_workspace`` (the switch to ``home``); with ``pose_timeout`` [s], ``pose_lost``
    (arm and fingers held where they were when the pose grew too old).
    """

    def __init__(
        self,
        hand: HandModel,
        reacher: Reacher,
        planner: ReachPlanner,
        estimator: ContactEstimator,
        kind: str,
        switch_distance: float = defaults.PREGRASP_SWITCH_DISTANCE,
        touch_distance: float = TOUCH_DISTANCE,
        timeout: float = GRASP_TIMEOUT,
        closing: FloatArray | None = None,
        grasp_hand: HandModel | None = None,
        gravity_compensation: bool = False,
        workspace: Workspace | None = None,
        pose_timeout: float | None = None,
    ) -> None:
        if kind not in ("pregrasp", "grasp"):
            raise ConfigError(f"ReachStage: kind must be 'pregrasp' or 'grasp', got {kind!r}")
        self.hand, self.reacher, self.planner, self.estimator = hand, reacher, planner, estimator
        self.kind = kind
        self.name = PREGRASP if kind == "pregrasp" else GRASP
        self.switch_distance, self.touch_distance = switch_distance, touch_distance
        self.timeout = timeout
        self.workspace, self.pose_timeout = workspace, pose_timeout
        self.palm_clamped = 0
        """Cycles whose targets were moved to keep the palm in the workspace's palm box."""
        self._held: FloatArray | None = None
        # An assembly's plans and targets are the hand's alone: joint angles in its order, base
        # poses of its root link. _hand_q places them in the assembly's q.
        self.grasp_hand = grasp_hand or hand
        self._hand_q = np.array(
            [hand.model.joints[hand.model.getJointId(n)].idx_q for n in self.grasp_hand.joint_names]
        )
        self._root = root_link(self.grasp_hand)
        self.squeeze = np.zeros(hand.nv) if closing is None else self._squeeze(closing)
        self.tips = [links[-1] for links in hand.config.fingers.values()]
        self.links = [hand.palm_link, *self.tips]
        self._kin = HandKinematics(self.grasp_hand)
        self.arm = ArmServo(hand) if hand.arm_dofs.any() else None
        self.gravity = GravityCompensation(hand) if gravity_compensation else None
        kp = np.full(hand.nv, FINGER_KP)
        kd = np.full(hand.nv, FINGER_KD)
        if self.arm is not None:
            kp[self.arm.dofs], kd[self.arm.dofs] = self.arm.kp, self.arm.kd
        self._kp, self._kd = kp, kd
        self._since = 0.0
        self._q_ref = np.zeros(hand.nq)
        self._wMb_ref = np.eye(4)
        self.reacher_times: deque[float] = deque(maxlen=TIMES_KEPT)
        """Wall time of the latest reacher steps [s]."""
        finger_of = {}
        for finger, links in hand.config.fingers.items():
            for link in links:
                if link in hand.link_names:
                    finger_of[hand.link_index(link)] = finger
        self._finger_of = finger_of
        self._dofs = np.arange(hand.nv)

    def start(self, context: CycleContext) -> None:
        self._since = context.t
        self._q_ref = context.obs.q.copy()
        self._wMb_ref = context.obs.wMb.copy()
        if self.kind == "pregrasp":
            assert context.obs.wMo is not None
            self.planner.choose(context.obs.wMo, self.grasp_base(context))

    def grasp_base(self, context: CycleContext) -> FloatArray:
        """(4, 4) world pose of the frame the plans place (the hand's root link)."""
        if self.grasp_hand is self.hand:
            return context.obs.wMb
        return context.kinematics.frame_pose(self._root)

    def _squeeze(self, closing: FloatArray) -> FloatArray:
        """(n_v,) how far past the grasp the finger servo closes [rad]: :data:`SQUEEZE` on the
        joints that ``closing`` (the grasp hand's (n_v,) closing torques) closes, their way."""
        squeeze = np.zeros(self.hand.nv)
        squeeze[self._hand_q] = SQUEEZE * np.sign(closing)
        return squeeze

    def fingers_touching(self, context: CycleContext) -> set[str]:
        """Fingers with a sample within ``touch_distance`` of the object (geometric estimate)."""
        assert context.obs.wMo is not None
        contacts = self.estimator.estimate(context.kinematics, context.obs.wMo)
        touching = contacts.link[contacts.distance <= self.touch_distance]
        return {self._finger_of[int(i)] for i in touching if int(i) in self._finger_of}

    def _hold(self, context: CycleContext) -> Command:
        """Arm and fingers held at the joint angles of the first cycle of the hold."""
        obs = context.obs
        if self._held is None:
            self._held = obs.q.copy()
            self._q_ref = obs.q.copy()
        return self._servo(obs, self._held, None)

    def _servo(self, obs: Observation, q_servo: FloatArray, base: FloatArray | None) -> Command:
        """Every joint servoed to ``q_servo`` (n_q,) with the gravity feed-forward terms."""
        tau = np.zeros(self.hand.nv)
        if self.gravity is not None:
            tau = self.hand.joint_torques(self.gravity.actuation_torques(obs.q, obs.wMb))
        if self.arm is not None:
            tau[self.arm.dofs] = self.arm.feedforward(obs.q, obs.wMb)
        servo = JointTargets(self._dofs, q_servo, None, self._kp, self._kd, name="joints")
        return Command(tau, (servo,), base=base)

    def _in_box(self, targets: dict[str, FloatArray]) -> dict[str, FloatArray]:
        """The targets moved together so that the palm's lies in the workspace's palm box."""
        assert self.workspace is not None
        palm = targets[self.hand.palm_link][:3, 3]
        shift = self.workspace.palm.clamp(palm) - palm
        if not shift.any():
            return targets
        self.palm_clamped += 1
        moved = {}
        for link, pose in targets.items():
            moved[link] = pose.copy()
            moved[link][:3, 3] += shift
        return moved

    def step(self, context: CycleContext) -> StageOutput:
        wMo = context.obs.wMo
        assert wMo is not None
        stop = self._stopped(context, wMo)
        if stop is not None:
            return stop
        self._held = None
        plan = self.planner.chosen
        if plan is None:
            plan = self.planner.choose(wMo, self.grasp_base(context))
            if plan is None:
                reason = (
                    f"no usable grasp plan at the object's pose ({len(self.planner.plans)} stored)"
                )
                return StageOutput(None, "no_plan", reason=reason)
        if self.kind == "pregrasp":
            q_goal, oMb_goal = plan.q_pre, plan.oMb_pre
        else:
            q_goal, oMb_goal = plan.q_grasp, plan.oMb_grasp
        targets = _targets(self._kin, q_goal, wMo @ oMb_goal, self.links)
        if self.workspace is not None:
            targets = self._in_box(targets)
        posture = self._q_ref.copy()
        posture[self._hand_q] = q_goal
        goal = ReachTargets(targets, posture, self.hand.palm_link, self.kind == "pregrasp")
        q_next, wMb_next = self._reach(context, wMo, goal)
        command = self._command(context, plan, targets, q_next, wMb_next)
        if self.kind == "pregrasp":
            return self._after_pregrasp_step(context, plan, targets, command)
        return self._after_grasp_step(context, plan, command)

    def _stopped(self, context: CycleContext, wMo: FloatArray) -> StageOutput | None:
        """On a robot: hold the arm and fingers while the pose is stale, go home when the
        object has left the workspace; None otherwise."""
        obs = context.obs
        if self.pose_timeout is not None and obs.stamp_q - obs.stamp_object > self.pose_timeout:
            return StageOutput(self._hold(context), "pose_lost")
        if self.workspace is not None and not self.workspace.object.contains(wMo[:3, 3]):
            reason = "the object left the arm's workspace: going home"
            return StageOutput(self._hold(context), "out_of_workspace", next=HOME, reason=reason)
        return None

    def _reach(
        self, context: CycleContext, wMo: FloatArray, goal: ReachTargets
    ) -> tuple[FloatArray, FloatArray]:
        """One reacher step toward ``goal`` from the servo's references; the next joint
        references and wrist pose (also kept as the references of the next cycle)."""
        obs = context.obs
        # The reacher integrates the servo's reference, not the reading: a reference one step
        # ahead of the reading would give the servo almost no error to act on. It may lead the
        # reading by MAX_LEAD at most, so a finger blocked by the object does not wind it up.
        q_ref = np.clip(self._q_ref, obs.q - MAX_LEAD, obs.q + MAX_LEAD)
        # Likewise the wrist of a floating hand (a target it is welded to): its reference,
        # unless the wrist has been held back by more than MAX_WRIST_LEAD.
        wMb_ref = self._wMb_ref
        if np.linalg.norm(wMb_ref[:3, 3] - obs.wMb[:3, 3]) > MAX_WRIST_LEAD:
            wMb_ref = obs.wMb
        started = time.perf_counter()
        q_next, wMb_next = self.reacher.step(q_ref, wMb_ref, wMo, goal, context.dt)
        self.reacher_times.append(time.perf_counter() - started)
        self._q_ref, self._wMb_ref = q_next, wMb_next
        return q_next, wMb_next

    def _command(
        self,
        context: CycleContext,
        plan: GraspPlan,
        targets: dict[str, FloatArray],
        q_next: FloatArray,
        wMb_next: FloatArray,
    ) -> Command:
        """The servo's command toward the reacher's step; in ``reach_grasp`` with the palm
        near its target, the joints squeezed past it by the closing torques."""
        palm = self.hand.palm_link
        palm_error = np.linalg.norm(
            context.kinematics.frame_pose(palm)[:3, 3] - targets[palm][:3, 3]
        )
        q_servo = q_next
        if self.kind == "grasp" and palm_error < SQUEEZE_PALM_ERROR:
            squeeze = self.squeeze if plan.closing is None else self._squeeze(plan.closing)
            q_servo = np.clip(q_next + squeeze, self.hand.q_lower, self.hand.q_upper)
        return self._servo(context.obs, q_servo, wMb_next if self.arm is None else None)

    def _after_pregrasp_step(
        self,
        context: CycleContext,
        plan: GraspPlan,
        targets: dict[str, FloatArray],
        command: Command,
    ) -> StageOutput:
        """To ``reach_grasp`` once the fingertips are at the pre-grasp; another plan when it
        is not reached within :data:`PREGRASP_TIMEOUT`."""
        now = context.kinematics
        errors = [np.linalg.norm(now.frame_pose(t)[:3, 3] - targets[t][:3, 3]) for t in self.tips]
        error = float(np.mean(errors))
        if error < self.switch_distance:
            reason = f"mean fingertip error {100 * error:.1f} cm < {100 * self.switch_distance} cm"
            return StageOutput(command, "reaching", next=GRASP, reason=reason)
        if context.t - self._since > PREGRASP_TIMEOUT:
            wMo = context.obs.wMo
            assert wMo is not None
            self.planner.fail()
            chosen = self.planner.choose(wMo, self.grasp_base(context))
            self._since = context.t
            then = "no usable plan left" if chosen is None else f"next: grasp {chosen.grasp_id}"
            reason = (
                f"pre-grasp not reached within {PREGRASP_TIMEOUT} s: grasp {plan.grasp_id}; {then}"
            )
            return StageOutput(command, "replan", reason=reason)
        return StageOutput(command, "reaching")

    def _after_grasp_step(
        self, context: CycleContext, plan: GraspPlan, command: Command
    ) -> StageOutput:
        """To ``regulate`` once the plan's fingers (else the thumb and two others) touch; back
        to ``reach_pregrasp`` when they do not within the timeout."""
        fingers = self.fingers_touching(context)
        thumb = self.hand.config.thumb
        if plan.fingers:
            grasped = set(plan.fingers) <= fingers
        else:
            grasped = thumb in fingers and len(fingers - {thumb}) >= 2
        if grasped:
            reason = f"touching: {', '.join(sorted(fingers))}"
            return StageOutput(command, "reaching", next=REGULATE, reason=reason)
        if context.t - self._since > self.timeout:
            self.planner.fail()
            reason = f"no grasp within {self.timeout} s (touching: {sorted(fingers)})"
            return StageOutput(command, "reaching", next=PREGRASP, reason=reason)
        return StageOutput(command, "reaching")


def reacher_faults(stages: Iterable[Stage]) -> dict[str, int]:
    """The reachers' :meth:`~wholehand.reaching.base.Reacher.fault_counts` over ``stages``'
    reach stages (each reacher once)."""
    reachers = {id(s.reacher): s.reacher for s in stages if isinstance(s, ReachStage)}
    total: Counter[str] = Counter()
    for reacher in reachers.values():
        total.update(reacher.fault_counts())
    return dict(total)


class HoldStage(Stage):
    """Force regulation until the grasp is lost (paper's criterion, on the tracked pose)."""

    name = REGULATE

    def __init__(self, regulation: ForceRegulation, loss: GraspLossCheck) -> None:
        self.regulation, self.loss = regulation, loss
        hand = regulation.hand
        self.arm = ArmServo(hand) if hand.arm_dofs.any() else None
        self._hold: JointTargets | None = None

    def preload(self, context: CycleContext) -> None:
        self.regulation.preload(context)

    def start(self, context: CycleContext) -> None:
        self.regulation.start(context)
        arm = self.arm
        if arm is not None:  # the arm stays where it grasped
            q = context.obs.q[arm.dofs].copy()
            self._hold = JointTargets(
                arm.dofs, q, None, np.asarray(arm.kp), np.asarray(arm.kd), "arm"
            )

    def step(self, context: CycleContext) -> StageOutput:
        assert context.obs.wMo is not None
        held = self.regulation.tracking_lost(context)
        if held is not None and held < TRACKING_HOLD + TRACKING_RAMP:
            # A pose the hand cannot be touching: the tracker's, not the grasp's (the last
            # torque is held, then ramped down); still so after the ramp, the grasp is lost.
            return self._with_arm(self.regulation.step(context), context)
        if held is not None:
            reason = f"grasp lost: the pose stayed out of the hand's reach for {held:.2f} s"
            return StageOutput(None, "lost", next=PREGRASP, reason=reason)
        if not self.loss.held(context.kinematics, context.obs.wMo):
            reason = "grasp lost: the hull of fingertips and palm left the object's box"
            return StageOutput(None, "lost", next=PREGRASP, reason=reason)
        return self._with_arm(self.regulation.step(context), context)

    def _with_arm(self, out: StageOutput, context: CycleContext) -> StageOutput:
        """The regulation's output with the arm held where it grasped (an assembly)."""
        if self.arm is None or out.command is None:
            return out
        assert self._hold is not None  # set by start
        tau = out.command.tau.copy()
        tau[self.arm.dofs] = self.arm.feedforward(context.obs.q, context.obs.wMb)
        return dataclasses.replace(out, command=Command(tau, (self._hold,)))
