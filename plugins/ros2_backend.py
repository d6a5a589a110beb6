"""The ``ros2`` backend: a real robot (or ``wholehand hw-sim``) over ROS 2 messages.

Subscribes ``sensor_msgs/msg/JointState``, the tracked object's ``geometry_msgs/msg/PoseStamped``
and a stop topic (``std_msgs/msg/Bool``); publishes the hand's torque commands as
``std_msgs/msg/Float64MultiArray`` (what ros2_control's
``forward_command_controller/ForwardCommandController`` with ``interface_name: effort`` reads on
``~/commands``) and, for an arm, its joint position targets (the same controller with
``interface_name: position``, or ``joint_trajectory_controller``).

The hand gets torques throughout: a stage's joint targets on hand joints (the reacher's finger
servo) become the PD law of :mod:`wholehand.loop.command` evaluated here on the newest joint
state, within the torque limits. With ``[topics] hand_position_command`` set, a command with
hand targets (reaching) instead sends the targets, within the joint limits, on that topic in the
torque command's joint order, for hand drivers that switch to a position interface on it, and
a command without (regulating) sends torques. Arm targets pass
:class:`~wholehand.hardware.arm_guard.ArmGuard`.
A stop request freezes the arm and ramps the hand torques to zero; on every exit (:meth:`close`,
reached on the loop's end, Ctrl-C, SIGTERM and a fault of the loop) the arm holds its measured
position and the hand torques ramp to zero over ``exit_ramp``.
Topics, joint names, rates, QoS and the safety limits come from a hardware config
(:mod:`wholehand.hardware.config`); messages go over zenoh as rmw_zenoh writes them
(:mod:`wholehand.hardware.rmw_zenoh`) or over DDS as rmw_cyclonedds and rmw_fastrtps write them
(:mod:`wholehand.hardware.ros2_dds`), by ``[ros2] transport``, so no ROS installation is
needed.

Every joint state is kept in the joint history, so the contacts of a pose are estimated at the
joint configuration of the pose's stamp (paper Sec. V-D). With ``sync_to_joint_states`` (the
default) a cycle whose newest joint state is no longer fresh waits for the next one, briefly
(:mod:`wholehand.hardware.config`), so that the torque answers a joint state just measured.
Incoming messages that fail their checks (:mod:`wholehand.hardware.inputs`), and samples the
transport drops (on zenoh those without rmw_zenoh's attachment, as rmw_zenoh drops them), are
counted by reason
and the last good sample stays; every outgoing torque passes the safety rules of
:class:`~wholehand.hardware.guard.TorqueGuard`, and a watchdog thread ramps the torque down when
the loop stops sending.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter, deque
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from wholehand.backends.base import Backend
from wholehand.errors import ConfigError
from wholehand.hardware.arm_guard import ArmGuard
from wholehand.hardware.config import HardwareConfig, load_hardware_config
from wholehand.hardware.guard import TorqueGuard
from wholehand.hardware.inputs import (
    JointSample,
    JointStateReader,
    RejectedMessage,
    arm_command_dofs,
    command_dofs,
    read_pose,
)
from wholehand.hardware.messages import (
    BOOL,
    FLOAT64_ARRAY,
    JOINT_STATE,
    JOINT_TRAJECTORY,
    POSE_STAMPED,
    MessageError,
    decode_bool,
    decode_joint_state,
    decode_pose,
    encode_array,
    encode_joint_trajectory,
)
from wholehand.hardware.transport import SampleMeta, open_transport
from wholehand.loop.command import Command
from wholehand.loop.observation import HISTORY_SAMPLES, JointHistory, Observation

if TYPE_CHECKING:
    from wholehand.models.hand import HandModel
    from wholehand.models.objects import ObjectModel

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

TRACE_SAMPLES = 100_000
"""Torque messages whose timing :attr:`Ros2Backend.trace` keeps (for ``wholehand bench hw``)."""

NODE_NAME = "wholehand_control"
"""The controller's node name in the ROS 2 graph (``ros2 node list``)."""

TRAJECTORY_LEAD = 2.0
"""A JointTrajectory's point is reached this many control periods after it is sent."""


def _position_targets(command: Command, n_v: int) -> FloatArray:
    """(n_v,) the command's position targets by velocity index [rad]; NaN where none."""
    target = np.full(n_v, np.nan)
    for group in command.targets:
        if group.q is not None:
            target[group.dofs] = group.q
    return target


class Ros2Backend(Backend):
    """A robot reached through ROS 2 messages over zenoh or DDS (wall clock).

    Args:
        hand: the hand (or arm-hand assembly) model.
        obj: the object model (unused here; the tracker reports its pose).
        config: a :class:`~wholehand.hardware.config.HardwareConfig` or the path of its TOML
            file (None: the defaults).
        q_init, wMo_init, gravity: ignored: a robot is where it is.
        history: joint samples kept for q at the pose's stamp.
        trace: keep the timing of every torque message (:attr:`trace`).

    Attributes:
        received: accepted messages per stream (``joint_states``, ``object_pose``).
        rejected: rejected messages per reason (``malformed``, ``not_finite``,
            ``unknown_joint``, ``wrong_length``, ``out_of_range``, ``wrong_frame``, ...).
        guard: the safety rules; ``guard.counts`` says how often each acted.
        sync: cycles by how they met the joint states (``fresh``: the newest was fresh;
            ``waited``: the next arrived within the wait; ``timed_out``: it did not).
        sync_wait: time the cycles spent waiting for joint states [s], in all.
        trace: ``(sequence number, stamp_q of the joint state used [s], publish time [ns])`` per
            torque message when ``trace`` is on.
    """

    clock = "wall"

    def __init__(
        self,
        hand: HandModel,
        obj: ObjectModel | None = None,
        config: HardwareConfig | str | Path | None = None,
        q_init: FloatArray | None = None,
        wMo_init: FloatArray | None = None,
        gravity: bool = False,
        history: int = HISTORY_SAMPLES,
        trace: bool = False,
    ) -> None:
        if not isinstance(config, HardwareConfig):
            config = load_hardware_config(config)
        self.config, self.hand = config, hand
        self.reader = JointStateReader(hand, config)
        self.command_dofs = command_dofs(hand, config)
        """(m,) velocity indices of the torque command's joints, in its order."""
        self.command_names = [self.reader.msg_name[hand.joint_names[i]] for i in self.command_dofs]
        """The torque command's joints as the robot names them (the effort controller's
        ``joints``, in order)."""
        has_arm = bool(config.topic("arm_command"))
        self.arm_dofs = arm_command_dofs(hand, config) if has_arm else np.zeros(0, np.intp)
        """(n_arm,) velocity indices of the arm command's joints, in its order."""
        self.arm_names = [self.reader.msg_name[hand.joint_names[i]] for i in self.arm_dofs]
        self.arm_guard: ArmGuard | None = None
        if has_arm:
            box = None if config.workspace is None else config.workspace.palm
            self.arm_guard = ArmGuard(hand, config.arm.velocity_scale, box)
            # ArmGuard works in model order; the command goes out in the controller's.
            self._arm_order = np.searchsorted(self.arm_guard.dofs, self.arm_dofs)
        self._q_index = np.array(
            [hand.model.joints[hand.model.getJointId(n)].idx_q for n in hand.joint_names]
        )
        self.history = JointHistory(hand.nq, history)
        self.guard = TorqueGuard(np.where(hand.actuated_dofs, hand.tau_max, 0.0), config.safety)
        self.stop_requested = False
        """A stop message asked the robot to stop (until one that releases it)."""
        self.stops = 0
        """Stop requests received (each true after a false or none)."""
        self.hand_position_messages = 0
        """Position commands sent to the hand (``[topics] hand_position_command``)."""
        self._hand_in_position = False
        self.received: Counter[str] = Counter()
        self.rejected: Counter[str] = Counter()
        self.last_rejection = ""
        self.trace: deque[tuple[int, float, int]] | None = (
            deque(maxlen=TRACE_SAMPLES) if trace else None
        )
        self.sync: Counter[str] = Counter()
        self.sync_wait = 0.0
        joint_period = 1.0 / config.joint_state_rate
        self._fresh_age = 0.25 * joint_period
        self._max_sync_wait = (
            min(1.25 * joint_period, 0.4 / config.control_rate)
            if config.sync_to_joint_states
            else 0.0
        )
        self._lock = threading.Lock()
        self._joint_arrived = threading.Condition(self._lock)
        self._pending: list[JointSample] = []
        self._joint: JointSample | None = None
        self._previous: JointSample | None = None
        self._joint_received = -np.inf
        self._pose: tuple[FloatArray, float] | None = None
        self._pose_received = -np.inf
        self._stamp_q_seen = np.nan
        self._last_apply = -np.inf
        self._closed = threading.Event()
        self.transport = transport = open_transport(config, NODE_NAME)
        try:
            self._torque = transport.publisher("torque_command", FLOAT64_ARRAY)
            arm_type = JOINT_TRAJECTORY if config.arm.interface == "trajectory" else FLOAT64_ARRAY
            self._arm = transport.publisher("arm_command", arm_type) if has_arm else None
            self._hand_position = (
                transport.publisher("hand_position_command", FLOAT64_ARRAY)
                if config.topic("hand_position_command")
                else None
            )
            self._subs = [
                transport.subscriber("joint_states", JOINT_STATE, self._on_joints, self._reject),
                transport.subscriber("object_pose", POSE_STAMPED, self._on_pose, self._reject),
            ]
            if config.topic("stop"):
                self._subs.append(transport.subscriber("stop", BOOL, self._on_stop, self._reject))
        except Exception:
            transport.close()
            raise
        self._watchdog = threading.Thread(
            target=self._watch, name="wholehand-watchdog", daemon=True
        )
        self._watchdog.start()

    # --- incoming (the transport's threads) -------------------------------------------------------
    def _reject(self, reason: str, detail: str) -> None:
        with self._lock:
            self.rejected[reason] += 1
            first = self.rejected[reason] == 1
            self.last_rejection = f"{reason}: {detail}"
        if first:
            log.warning("rejected a message (%s): %s", reason, detail)

    def _on_joints(self, payload: bytes, meta: SampleMeta, received: float) -> None:
        try:
            sample = self.reader.read(decode_joint_state(payload), time.time())
        except MessageError as err:
            self._reject("malformed", str(err))
            return
        except RejectedMessage as err:
            self._reject(err.reason, str(err))
            return
        with self._lock:
            if self._joint is not None and sample.stamp <= self._joint.stamp:
                self.rejected["old_stamp"] += 1
                return
            self._previous, self._joint = self._joint, sample
            self._joint_received = received
            self._pending.append(sample)
            self.received["joint_states"] += 1
            self._joint_arrived.notify_all()

    def _on_pose(self, payload: bytes, meta: SampleMeta, received: float) -> None:
        config = self.config
        try:
            msg = decode_pose(payload)
            wMo = read_pose(msg, config.frame_id, time.time(), config.safety.max_future_stamp)
        except MessageError as err:
            self._reject("malformed", str(err))
            return
        except RejectedMessage as err:
            self._reject(err.reason, str(err))
            return
        stamp = msg.stamp if config.stamp_source == "header" else time.time()
        with self._lock:
            if self._pose is not None and stamp <= self._pose[1]:
                self.rejected["old_stamp"] += 1
                return
            self._pose = (wMo, stamp)
            self._pose_received = received
            self.received["object_pose"] += 1

    def _on_stop(self, payload: bytes, meta: SampleMeta, received: float) -> None:
        try:
            stop = decode_bool(payload)
        except MessageError as err:
            self._reject("malformed", str(err))
            return
        with self._lock:
            if stop and not self.stop_requested:
                self.stops += 1
                log.warning(
                    "stop requested on %s: arm frozen, hand ramping to zero",
                    self.config.topic("stop"),
                )
            self.stop_requested = stop

    # --- Backend interface ----------------------------------------------------------------------
    def wait_for_streams(self, timeout: float) -> None:
        """Block until a first joint state and a first object pose have arrived.

        Raises:
            ConfigError: one of them did not within ``timeout`` [s] (named, with what was
                rejected meanwhile).
        """
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self._lock:
                if self._joint is not None and self._pose is not None:
                    return
            time.sleep(0.01)
        topics = self.config.topics
        missing = [
            f"{kind} on {topics[key]!r}"
            for kind, key, got in (
                ("no joint state", "joint_states", self._joint),
                ("no object pose", "object_pose", self._pose),
            )
            if got is None
        ]
        rejected = f"; rejected meanwhile: {dict(self.rejected)} (last: {self.last_rejection})"
        raise ConfigError(
            f"{' and '.join(missing)} within {timeout:g} s ({self.config.link()})"
            f"{rejected if self.rejected else ''}; check that the robot publishes, the topic "
            "names in [topics] and the transport settings in [ros2] (docs/hardware.md)"
        )

    def observe(self) -> Observation:
        """The newest joint state (every one since the last call goes into the history) and the
        newest object pose. Before a first joint state, q is NaN (the loop's ``bad_state``)."""
        with self._lock:
            pending, self._pending = self._pending, []
            joint, previous, pose = self._joint, self._previous, self._pose
        for sample in pending:
            self.history.push(sample.stamp, sample.q, self.hand.wMb)
        if joint is None:
            unknown = np.full(self.hand.nq, np.nan)
            return Observation(
                unknown, np.zeros(self.hand.nv), self.hand.wMb, 0.0, None, 0.0, self.history
            )
        dq = joint.dq if joint.dq is not None else self._velocity(joint, previous)
        self._stamp_q_seen = joint.stamp
        wMo, stamp_object = (None, joint.stamp) if pose is None else pose
        return Observation(joint.q, dq, self.hand.wMb, joint.stamp, wMo, stamp_object, self.history)

    def apply(self, command: Command) -> None:
        """Send the command's hand torques (its hand targets as a PD law in torque) through the
        torque guard and its arm targets through the arm guard; on a stop request, the arm's
        frozen target and the hand's ramp to zero instead."""
        with self._lock:
            now, stamp_ns = time.monotonic(), time.time_ns()
            joint, joint_age = self._joint, now - self._joint_received
            pose_age = self._pose_age(now, joint)
            self._last_apply = now
            if joint is not None:
                self.guard.start_from(joint.effort, now)
            positions, position_pub = None, self._hand_position
            self._hand_in_position = False
            if self.stop_requested:
                tau = self.guard.ramp_down(now, self.config.safety.pose_ramp, "stop")
            elif position_pub is not None and joint_age <= self.config.safety.joint_timeout:
                positions = self._hand_targets(command)
            if positions is not None and position_pub is not None:
                position_pub.put(encode_array(positions))
                self.hand_position_messages += 1
                self._hand_in_position = True
                # The drives servo the position; the first torque command after it is
                # rate-limited from the effort they then report, as after a restart.
                self.guard.last = None
            else:
                if not self.stop_requested:
                    wanted = self._hand_torques(command, joint)
                    tau, _ = self.guard.filter(wanted, now, joint_age, pose_age)
                self._publish(tau, stamp_ns)
            arm = self._arm_target(command, joint, joint_age, now)
        if arm is not None:
            self._publish_arm(arm)

    def _pose_age(self, now: float, joint: JointSample | None) -> float:
        """Age of the newest pose [s]: since it arrived, or, with header stamps, how much older
        its stamp is than the newest joint state's, whichever is larger (a stalled tracker that
        keeps sending its last, old-stamped pose gets the stale-pose rule)."""
        age = now - self._pose_received
        if self.config.stamp_source == "header" and joint is not None and self._pose is not None:
            age = max(age, joint.stamp - self._pose[1])
        return age

    def _hand_targets(self, command: Command) -> FloatArray | None:
        """(m,) the command's position targets of the hand's command joints, in their order and
        within their limits; None unless the command targets every one of them."""
        out = _position_targets(command, self.hand.nv)[self.command_dofs]
        if not np.isfinite(out).all():
            return None
        q_index = self._q_index[self.command_dofs]
        return np.clip(out, self.hand.q_lower[q_index], self.hand.q_upper[q_index])

    def _hand_torques(self, command: Command, joint: JointSample | None) -> FloatArray:
        """(n_v,) the command's torques with each target group's PD law on the hand's joints,
        evaluated on the newest joint state (:mod:`wholehand.loop.command`); zero on an arm's
        joints."""
        tau = command.tau.copy()
        tau[self.hand.arm_dofs] = 0.0  # the arm's own controller holds it; not sent
        if not command.targets or joint is None:
            return tau
        dq = joint.dq if joint.dq is not None else self._velocity(joint, self._previous)
        for group in command.targets:
            hand = ~self.hand.arm_dofs[group.dofs]
            dofs = group.dofs[hand]
            if not dofs.size:
                continue
            dq_ref = 0.0 if group.dq is None else group.dq[hand]
            tau[dofs] += group.kd[hand] * (dq_ref - dq[dofs])
            if group.q is not None:
                tau[dofs] += group.kp[hand] * (group.q[hand] - joint.q[self._q_index[dofs]])
        return tau

    def _arm_target(
        self, command: Command, joint: JointSample | None, joint_age: float, now: float
    ) -> FloatArray | None:
        """(n_arm,) the arm target to send, model order, through the arm guard; None when there
        is no arm, no joint state yet, or the command gives the arm no full target."""
        guard = self.arm_guard
        if guard is None or joint is None:
            return None
        if self.stop_requested or not joint_age <= self.config.safety.joint_timeout:
            # Frozen where the arm was when it began (a stale joint state: its last target).
            if guard.last is None or (self.stop_requested and guard.counts["hold"] == 0):
                return guard.hold(joint.q, now)
            return guard.last
        arm = _position_targets(command, self.hand.nv)[guard.dofs]
        if not np.isfinite(arm).all():
            return None
        return guard.filter(arm, joint.q, now)[0]

    def _publish_arm(self, target: FloatArray) -> None:
        """Publish the arm's target (n_arm,) [rad], model order, in the arm controller's order."""
        assert self._arm is not None
        out = target[self._arm_order]
        if self.config.arm.interface == "trajectory":
            lead = TRAJECTORY_LEAD / self.config.control_rate
            self._arm.put(encode_joint_trajectory(self.arm_names, out, lead))
        else:
            self._arm.put(encode_array(out))

    def _velocity(self, joint: JointSample, previous: JointSample | None) -> FloatArray:
        """(n_v,) joint velocities of a state sent without them: the difference of the last two
        samples (zero for a first sample)."""
        if previous is None:
            return np.zeros(self.hand.nv)
        return (joint.q - previous.q) / (joint.stamp - previous.stamp)

    def _publish(self, tau: FloatArray, stamp_ns: int) -> None:
        """Publish ``tau``'s command joints, stamped (attachment) with the guard's time of it, so
        that the rate a receiver measures is the rate the guard limited."""
        self._torque.put(encode_array(tau[self.command_dofs]), stamp_ns)
        if self.trace is not None:
            self.trace.append((self._torque.sequence_number, self._stamp_q_seen, stamp_ns))

    def step(self, duration: float) -> None:
        """Wait ``duration`` [s], then, with ``sync_to_joint_states``, for a fresh joint state
        (:mod:`wholehand.hardware.config`; counted in :attr:`sync`)."""
        if duration > 0.0:
            time.sleep(duration)
        if self._max_sync_wait > 0.0:
            self._wait_for_fresh_joints()

    def _wait_for_fresh_joints(self) -> None:
        with self._joint_arrived:
            received = self._joint_received
            started = time.monotonic()
            if self._joint is None:
                return  # nothing to wait for: the cycle reports bad_state
            if started - received < self._fresh_age:
                self.sync["fresh"] += 1
                return
            arrived = self._joint_arrived.wait_for(
                lambda: self._joint_received != received, timeout=self._max_sync_wait
            )
            self.sync["waited" if arrived else "timed_out"] += 1
            self.sync_wait += time.monotonic() - started

    @property
    def time(self) -> float:
        """This process's monotonic clock [s]."""
        return time.monotonic()

    # --- the watchdog ---------------------------------------------------------------------------
    def _watch(self) -> None:
        limit = self.config.safety.watchdog
        while not self._closed.wait(limit / 4.0):
            with self._lock:
                now, stamp_ns = time.monotonic(), time.time_ns()
                if np.isfinite(self._last_apply) and now - self._last_apply > limit:
                    self._publish(self.guard.watchdog(now), stamp_ns)

    # --- extras ---------------------------------------------------------------------------------
    def stats(self) -> dict[str, Any]:
        """Counts of received and rejected messages and of the safety rules, JSON-ready."""
        with self._lock:
            return {
                "received": dict(self.received),
                "rejected": dict(self.rejected),
                "last_rejection": self.last_rejection,
                "guard": dict(self.guard.counts),
                "torque_messages": self._torque.sequence_number,
                "command_joints": self.command_names,
                "arm_guard": {} if self.arm_guard is None else dict(self.arm_guard.counts),
                "arm_messages": 0 if self._arm is None else self._arm.sequence_number,
                "arm_joints": self.arm_names,
                "stops": self.stops,
                "hand_position_messages": self.hand_position_messages,
                "sync": dict(self.sync),
                "sync_wait_s": self.sync_wait,
            }

    def close(self) -> None:
        """Send the last commands (:meth:`release`), stop the watchdog and leave the
        network."""
        if self._closed.is_set():
            return
        self._closed.set()
        self._watchdog.join()
        self.release()
        for sub in self._subs:
            sub.close()
        self._torque.close()
        if self._arm is not None:
            self._arm.close()
        if self._hand_position is not None:
            self._hand_position.close()
        self.transport.close()

    def release(self) -> None:
        """The last commands of every exit: the arm's target at its measured position, and the
        hand's torque ramped from the last one sent to zero over ``exit_ramp`` at the control
        rate, ending on zero (counted as ``exit`` in the guard); a hand last sent position
        targets (``hand_position_command``) gets its measured position instead. Nothing when no
        command was ever sent."""
        if self.guard.last is None and not self._hand_in_position:
            return
        duration, period = self.config.safety.exit_ramp, 1.0 / self.config.control_rate
        with self._lock:
            joint = self._joint
            arm = None
            if self.arm_guard is not None and joint is not None:
                arm = self.arm_guard.hold(joint.q, time.monotonic())
        if arm is not None:
            self._publish_arm(arm)
        if self._hand_in_position:
            if joint is not None and self._hand_position is not None:
                held = joint.q[self._q_index[self.command_dofs]]
                self._hand_position.put(encode_array(held))
                self.hand_position_messages += 1
            return
        start = time.monotonic()
        while True:
            now = time.monotonic()
            with self._lock:
                tau = self.guard.ramp_down(now, duration, "exit")
                self._publish(tau, time.time_ns())
            if not tau.any():
                break
            time.sleep(max(0.0, min(period, start + duration - now)))
        if arm is not None:
            self._publish_arm(arm)

    def __enter__(self) -> Ros2Backend:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
