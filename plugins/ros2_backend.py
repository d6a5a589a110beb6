"""The ``ros2`` backend: a real robot (or ``wholehand hw-sim``) over ROS 2 messages.

Subscribes ``sensor_msgs/msg/JointState``, the tracked object's ``geometry_msgs/msg/PoseStamped``
and a stop topic (``std_msgs/msg/Bool``); publishes the hand's torque commands as
``std_msgs/msg/Float64MultiArray`` (what ros2_control's
``forward_command_controller/ForwardCommandController`` with ``interface_name: effort`` reads on
``~/commands``) and, for an arm, its joint position targets (the same controller with
``interface_name: position``, or ``joint_trajectory_controller``).

The hand gets torques throughout: a stage's joint targets on hand joints (the reacher's finger
servo) become the PD law of :mod:`wholehand.backends.command` evaluated here on the newest joint
state, within the torque limits. With ``[topics] hand_position_command`` set, a command with
hand targets (reaching) instead sends the targets, within the joint limits, on that topic in the
torque command's joint order, for hand drivers that switch to a position interface on it, and
a command without (regulating) sends torques. Arm targets pass
:class:`~wholehand.robot.arm_guard.ArmGuard`.
A stop request freezes the arm and ramps the hand torques to zero; on every exit (:meth:`close`,
reached on the loop's end, Ctrl-C, SIGTERM and a fault of the loop) the arm holds its measured
position and the hand torques ramp to zero over ``exit_ramp``.
Topics, joint names, rates, QoS and the safety limits come from a hardware config
(:mod:`wholehand.ros2.config_file`); messages go over zenoh as rmw_zenoh writes them
(:mod:`wholehand.ros2.rmw_zenoh`) or over DDS as rmw_cyclonedds and rmw_fastrtps write them
(:mod:`wholehand.ros2.ros2_dds`), by ``[ros2] transport``, so no ROS installation is
needed.

Every joint state is kept in the joint history, so the contacts of a pose are estimated at the
joint configuration of the pose's stamp (paper Sec. V-D). With ``sync_to_joint_states`` (the
default) a cycle whose newest joint state is no longer fresh waits for the next one, briefly
(:mod:`wholehand.ros2.config_file`), so that the torque answers a joint state just measured.
Incoming messages are read by :class:`~wholehand.ros2.streams.RobotStreams`: those that
fail their checks (:mod:`wholehand.ros2.inputs`), and samples the transport drops (on zenoh
those without rmw_zenoh's attachment, as rmw_zenoh drops them), are counted by reason and the
last good sample stays. Every outgoing torque passes the safety rules of
:class:`~wholehand.robot.guard.TorqueGuard`, and a watchdog thread ramps the torque down when
the loop stops sending.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from wholehand.backends.base import Backend
from wholehand.backends.command import Command
from wholehand.backends.observation import HISTORY_SAMPLES, JointHistory, Observation
from wholehand.robot.arm_guard import ArmGuard
from wholehand.robot.guard import TorqueGuard
from wholehand.ros2.config import HardwareConfig
from wholehand.ros2.config_file import load_hardware_config
from wholehand.ros2.inputs import JointSample, JointStateReader, arm_command_dofs, command_dofs
from wholehand.ros2.joint_sync import JointSync
from wholehand.ros2.messages import (
    FLOAT64_ARRAY,
    JOINT_TRAJECTORY,
    STRING,
    encode_array,
    encode_joint_trajectory,
    encode_string,
)
from wholehand.ros2.node import open_transport
from wholehand.ros2.streams import Latest, RobotStreams

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
        config: a :class:`~wholehand.ros2.config.HardwareConfig` or the path of its TOML
            file (None: the defaults).
        q_init, wMo_init, gravity: ignored: a robot is where it is.
        history: joint samples kept for q at the pose's stamp.
        trace: keep the timing of every torque message (:attr:`trace`).
        clock: the clock of every timeout, ramp and message age [s]; a robot runs on
            ``time.monotonic``, a test may run it ahead instead of sleeping.

    Attributes:
        received: accepted messages per stream (``joint_states``, ``object_pose``).
        rejected: rejected messages per reason (``malformed``, ``not_finite``,
            ``unknown_joint``, ``wrong_length``, ``out_of_range``, ``wrong_frame``, ...).
        guard: the safety rules; ``guard.counts`` says how often each acted.
        joint_sync: the wait for a fresh joint state before each cycle
            (:class:`~wholehand.ros2.joint_sync.JointSync`); ``sync`` and ``sync_wait`` are its
            counts by how the cycles met the joint states and its time waited [s].
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
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not isinstance(config, HardwareConfig):
            config = load_hardware_config(config)
        self.config, self.hand = config, hand
        self._clock = clock
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
        self.guard = TorqueGuard(
            np.where(hand.actuated_dofs, hand.tau_max, 0.0),
            config.safety,
            period=1.0 / config.control_rate,
        )
        self.hand_position_messages = 0
        """Position commands sent to the hand (``[topics] hand_position_command``)."""
        self.status_messages = 0
        """Status messages sent (``[topics] status``)."""
        self._hand_in_position = False
        self.trace: deque[tuple[int, float, int]] | None = (
            deque(maxlen=TRACE_SAMPLES) if trace else None
        )
        self.joint_sync = JointSync(config, self._clock)
        self._lock = threading.Lock()
        """Guards the torque guard, the publishers and the apply time (loop and watchdog)."""
        self._stamp_q_seen = np.nan
        self._last_apply = -np.inf
        self._closed = threading.Event()
        self._stamp0 = time.time_ns()
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
            self._status = transport.publisher("status", STRING) if config.topic("status") else None
            self.streams = RobotStreams(config, self.reader, transport, clock)
        except Exception:
            transport.close()
            raise
        self._watchdog = threading.Thread(
            target=self._watch, name="wholehand-watchdog", daemon=True
        )
        self._watchdog.start()

    # --- the streams' counts, for callers and tests --------------------------------------------
    @property
    def received(self) -> Counter[str]:
        """Accepted messages per stream (:class:`~wholehand.ros2.streams.RobotStreams`)."""
        return self.streams.received

    @property
    def rejected(self) -> Counter[str]:
        """Rejected messages per reason."""
        return self.streams.rejected

    @property
    def last_rejection(self) -> str:
        return self.streams.last_rejection

    @property
    def stop_requested(self) -> bool:
        """A stop message asked the robot to stop (until one that releases it)."""
        return self.streams.stop_requested

    # --- Backend interface ----------------------------------------------------------------------
    def wait_for_streams(self, timeout: float) -> None:
        """Block until a first joint state and a first object pose have arrived.

        Raises:
            ConfigError: one of them did not within ``timeout`` [s] (named, with what was
                rejected meanwhile).
        """
        self.streams.wait_for_first(timeout)

    def observe(self) -> Observation:
        """The newest joint state (every one since the last call goes into the history) and the
        newest object pose. Before a first joint state, q is NaN (the loop's ``bad_state``)."""
        for sample in self.streams.take_pending():
            self.history.push(sample.stamp, sample.q, self.hand.wMb)
        latest = self.streams.latest()
        joint, previous, pose = latest.joint, latest.previous, latest.pose
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
        latest = self.streams.latest()
        stop = latest.stop_requested
        with self._lock:
            now, stamp_ns = self._clock(), time.time_ns()
            stamp = self._guard_stamp(stamp_ns)  # the guard limits the rate between stamps too
            joint, joint_age = latest.joint, now - latest.joint_received
            pose_age = self._pose_age(now, latest)
            self._last_apply = now
            self.joint_sync.computed(now)
            if joint is not None:
                self.guard.start_from(joint.effort, now)
            positions, position_pub = None, self._hand_position
            self._hand_in_position = False
            if stop:
                tau = self.guard.ramp_down(now, self.config.safety.pose_ramp, "stop", stamp)
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
                if not stop:
                    wanted = self._hand_torques(command, joint, latest.previous)
                    tau, _ = self.guard.filter(wanted, now, joint_age, pose_age, stamp)
                self._publish(tau, stamp_ns)
            arm = self._arm_target(command, joint, joint_age, now, stop)
        if arm is not None:
            self._publish_arm(arm)

    def _guard_stamp(self, stamp_ns: int) -> float:
        """A message stamp [ns] as the guard takes it: [s] since this backend started (exact to
        the nanosecond, where seconds since 1970 in a float are not)."""
        return 1e-9 * (stamp_ns - self._stamp0)

    def _pose_age(self, now: float, latest: Latest) -> float:
        """Age of the newest pose [s]: since it arrived, or, with header stamps, how much older
        its stamp is than the newest joint state's, whichever is larger (a stalled tracker that
        keeps sending its last, old-stamped pose gets the stale-pose rule)."""
        age = now - latest.pose_received
        joint, pose = latest.joint, latest.pose
        if self.config.stamp_source == "header" and joint is not None and pose is not None:
            age = max(age, joint.stamp - pose[1])
        return age

    def _hand_targets(self, command: Command) -> FloatArray | None:
        """(m,) the command's position targets of the hand's command joints, in their order and
        within their limits; None unless the command targets every one of them."""
        out = _position_targets(command, self.hand.nv)[self.command_dofs]
        if not np.isfinite(out).all():
            return None
        q_index = self._q_index[self.command_dofs]
        return np.clip(out, self.hand.q_lower[q_index], self.hand.q_upper[q_index])

    def _hand_torques(
        self, command: Command, joint: JointSample | None, previous: JointSample | None
    ) -> FloatArray:
        """(n_v,) the command's torques with each target group's PD law on the hand's joints,
        evaluated on the newest joint state (:mod:`wholehand.backends.command`); zero on an arm's
        joints."""
        tau = command.tau.copy()
        tau[self.hand.arm_dofs] = 0.0  # the arm's own controller holds it; not sent
        if not command.targets or joint is None:
            return tau
        dq = joint.dq if joint.dq is not None else self._velocity(joint, previous)
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
        self,
        command: Command,
        joint: JointSample | None,
        joint_age: float,
        now: float,
        stop: bool,
    ) -> FloatArray | None:
        """(n_arm,) the arm target to send, model order, through the arm guard; None when there
        is no arm, no joint state yet, or the command gives the arm no full target."""
        guard = self.arm_guard
        if guard is None or joint is None:
            return None
        if stop or not joint_age <= self.config.safety.joint_timeout:
            # Frozen where the arm was when it began (a stale joint state: its last target).
            if guard.last is None or (stop and guard.counts["hold"] == 0):
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

    def publish_status(self, text: str) -> None:
        """Publish ``text`` (the controller's stage) on the status topic (nothing without one)."""
        if self._status is None:
            return
        payload = encode_string(text)
        with self._lock:
            self._status.put(payload)
            self.status_messages += 1

    def step(self, duration: float) -> None:
        """Wait ``duration`` [s], then, with ``sync_to_joint_states``, for a fresh joint state
        (:mod:`wholehand.ros2.config_file`; counted in :attr:`sync`)."""
        if duration > 0.0:
            time.sleep(duration)
        self.joint_sync.wait(self.streams)

    @property
    def sync(self) -> Counter[str]:
        """Cycles by how they met the joint states (:class:`JointSync`'s ``counts``)."""
        return self.joint_sync.counts

    @property
    def sync_wait(self) -> float:
        """Time the cycles spent waiting for joint states [s], in all."""
        return self.joint_sync.waited

    @property
    def time(self) -> float:
        """The backend's clock [s] (``clock``: this process's monotonic clock)."""
        return self._clock()

    # --- the watchdog ---------------------------------------------------------------------------
    def _watch(self) -> None:
        limit = self.config.safety.watchdog
        while not self._closed.wait(limit / 4.0):
            with self._lock:
                now, stamp_ns = self._clock(), time.time_ns()
                if np.isfinite(self._last_apply) and now - self._last_apply > limit:
                    self._publish(self.guard.watchdog(now, self._guard_stamp(stamp_ns)), stamp_ns)

    # --- extras ---------------------------------------------------------------------------------
    def stats(self) -> dict[str, Any]:
        """Counts of received and rejected messages and of the safety rules, JSON-ready."""
        streams = self.streams
        with self._lock:
            return {
                "received": dict(streams.received),
                "rejected": dict(streams.rejected),
                "arrived": dict(streams.arrived),
                "superseded": streams.superseded,
                "last_rejection": streams.last_rejection,
                "guard": dict(self.guard.counts),
                "joint_gaps": self.guard.gaps.summary(),
                "torque_messages": self._torque.sequence_number,
                "command_joints": self.command_names,
                "arm_guard": {} if self.arm_guard is None else dict(self.arm_guard.counts),
                "arm_messages": 0 if self._arm is None else self._arm.sequence_number,
                "arm_joints": self.arm_names,
                "stops": streams.stops,
                "hand_position_messages": self.hand_position_messages,
                "status_messages": self.status_messages,
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
        self.streams.close()
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
        joint = self.streams.latest().joint
        with self._lock:
            arm = None
            if self.arm_guard is not None and joint is not None:
                arm = self.arm_guard.hold(joint.q, self._clock())
        if arm is not None:
            self._publish_arm(arm)
        if self._hand_in_position:
            if joint is not None and self._hand_position is not None:
                held = joint.q[self._q_index[self.command_dofs]]
                self._hand_position.put(encode_array(held))
                self.hand_position_messages += 1
            return
        start = self._clock()
        while True:
            now, stamp_ns = self._clock(), time.time_ns()
            with self._lock:
                tau = self.guard.ramp_down(now, duration, "exit", self._guard_stamp(stamp_ns))
                self._publish(tau, stamp_ns)
            if not tau.any():
                break
            time.sleep(max(0.0, min(period, start + duration - now)))
        if arm is not None:
            self._publish_arm(arm)

    def __enter__(self) -> Ros2Backend:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
