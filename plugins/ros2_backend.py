"""The ``ros2`` backend: a real robot (or ``wholehand hw-sim``) over ROS 2 messages on zenoh.

Subscribes ``sensor_msgs/msg/JointState`` and the tracked object's
``geometry_msgs/msg/PoseStamped``; publishes torque commands as ``std_msgs/msg/Float64MultiArray``
(what ros2_control's ``effort_controllers/JointGroupEffortController`` reads on ``~/commands``)
and, for an arm, joint position targets (``position_controllers/JointGroupPositionController``).
Topics, joint names, rates, QoS and the safety limits come from a hardware config
(:mod:`wholehand.hardware.config`); messages go over zenoh as rmw_zenoh writes them
(:mod:`wholehand.hardware.rmw_zenoh`), so no ROS installation is needed.

Every joint state is kept in the joint history, so the contacts of a pose are estimated at the
joint configuration of the pose's stamp (paper Sec. V-D). With ``sync_to_joint_states`` (the
default) a cycle whose newest joint state is no longer fresh waits for the next one, briefly
(:mod:`wholehand.hardware.config`), so that the torque answers a joint state just measured.
Incoming messages that fail their checks (:mod:`wholehand.hardware.inputs`) are counted by reason
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
from wholehand.hardware.config import HardwareConfig, load_hardware_config
from wholehand.hardware.guard import TorqueGuard
from wholehand.hardware.inputs import (
    JointSample,
    JointStateReader,
    RejectedMessage,
    command_dofs,
    read_pose,
)
from wholehand.hardware.messages import (
    FLOAT64_ARRAY,
    JOINT_STATE,
    POSE_STAMPED,
    MessageError,
    decode_joint_state,
    decode_pose,
    encode_array,
)
from wholehand.hardware.rmw_zenoh import Publisher, Subscriber, open_session
from wholehand.loop.command import Command
from wholehand.loop.observation import HISTORY_SAMPLES, JointHistory, Observation

if TYPE_CHECKING:
    from wholehand.models.hand import HandModel
    from wholehand.models.objects import ObjectModel

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

TRACE_SAMPLES = 100_000
"""Torque messages whose timing :attr:`Ros2Backend.trace` keeps (for ``wholehand bench hw``)."""


class Ros2Backend(Backend):
    """A robot reached through ROS 2 messages over zenoh (wall clock).

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
        self.arm_dofs = np.flatnonzero(hand.arm_dofs)
        self.history = JointHistory(hand.nq, history)
        self.guard = TorqueGuard(np.where(hand.actuated_dofs, hand.tau_max, 0.0), config.safety)
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
        self.session = open_session(config)
        try:
            self._torque = Publisher(self.session, config, "torque_command", FLOAT64_ARRAY)
            self._arm = (
                Publisher(self.session, config, "arm_command", FLOAT64_ARRAY)
                if config.topics["arm_command"]
                else None
            )
            self._subs = [
                Subscriber(self.session, config, "joint_states", JOINT_STATE, self._on_joints),
                Subscriber(self.session, config, "object_pose", POSE_STAMPED, self._on_pose),
            ]
        except Exception:
            self.session.close()
            raise
        self._watchdog = threading.Thread(
            target=self._watch, name="wholehand-watchdog", daemon=True
        )
        self._watchdog.start()

    # --- incoming (zenoh's threads) -------------------------------------------------------------
    def _reject(self, reason: str, detail: str) -> None:
        with self._lock:
            self.rejected[reason] += 1
            first = self.rejected[reason] == 1
            self.last_rejection = f"{reason}: {detail}"
        if first:
            log.warning("rejected a message (%s): %s", reason, detail)

    def _on_joints(self, payload: bytes, attachment: bytes | None, received: float) -> None:
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

    def _on_pose(self, payload: bytes, attachment: bytes | None, received: float) -> None:
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
            f"{' and '.join(missing)} within {timeout:g} s (zenoh connect="
            f"{list(self.config.connect)} listen={list(self.config.listen)}, domain "
            f"{self.config.domain_id}){rejected if self.rejected else ''}; check that the robot "
            "publishes, the topic names in [topics] and the endpoints in [ros2]"
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
        dq = joint.dq
        if dq is None:  # no velocities sent: the difference of the last two samples
            dq = np.zeros(self.hand.nv)
            if previous is not None:
                dq = (joint.q - previous.q) / (joint.stamp - previous.stamp)
        self._stamp_q_seen = joint.stamp
        wMo, stamp_object = (None, joint.stamp) if pose is None else pose
        return Observation(joint.q, dq, self.hand.wMb, joint.stamp, wMo, stamp_object, self.history)

    def apply(self, command: Command) -> None:
        """Send the command's torques through the safety rules (and the arm's targets)."""
        with self._lock:
            now, stamp_ns = time.monotonic(), time.time_ns()
            joint, joint_age = self._joint, now - self._joint_received
            pose_age = now - self._pose_received
            self._last_apply = now
            if joint is not None:
                self.guard.start_from(joint.effort, now)
            tau, _ = self.guard.filter(command.tau, now, joint_age, pose_age)
            self._publish(tau, stamp_ns)
        if self._arm is not None and command.targets:
            self._publish_arm(command)

    def _publish_arm(self, command: Command) -> None:
        """The arm's position targets [rad], in model order, when the command's target groups
        give every arm joint one (the position controller takes all its joints at once)."""
        assert self._arm is not None
        target = np.full(self.hand.nv, np.nan)
        for group in command.targets:
            if group.q is not None:
                target[group.dofs] = group.q
        arm = target[self.arm_dofs]
        if self.arm_dofs.size and np.isfinite(arm).all():
            self._arm.put(encode_array(arm))

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
                "sync": dict(self.sync),
                "sync_wait_s": self.sync_wait,
            }

    def close(self) -> None:
        """Stop the watchdog and leave the zenoh session (the drives keep the last torque until
        their own command timeout)."""
        if self._closed.is_set():
            return
        self._closed.set()
        self._watchdog.join()
        for sub in self._subs:
            sub.close()
        self._torque.close()
        if self._arm is not None:
            self._arm.close()
        self.session.close()

    def __enter__(self) -> Ros2Backend:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
