"""What the robot sends the controller: joint states, object poses and stop requests.

Each message is decoded and checked when it arrives, on the transport's thread
(:mod:`wholehand.ros2.inputs`); the newest good one of each stream is kept with its receipt
time on the streams' clock (``time.monotonic`` unless a test gives its own), and a message that
fails a check, or is older than the newest, is counted by reason (:attr:`RobotStreams.rejected`)
while the last good one stays.

A flood of joint states (thousands a second, good or bad, from a misconfigured driver or a
hostile node) must not starve the control cycle: decoding one costs ~30 us of Python, which
holds the interpreter's lock. Joint states are decoded on arrival at most at one per
:data:`DECODE_SPACING` on average, in bursts of up to :data:`DECODE_BURST` (a token bucket);
one past that is only kept, undecoded, in place of any other so kept (which is counted
``superseded``), and the controller decodes it when it next reads the streams. At the rates
robots send (up to 1 kHz, jitter and bursts included) every message is still decoded and
checked on arrival; under a flood the transport's threads decode 2000 a second and the
controller one per cycle, and every message delivered is counted once: accepted, rejected (by
reason) or superseded.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from wholehand.errors import ConfigError
from wholehand.ros2.config import HardwareConfig
from wholehand.ros2.inputs import JointSample, JointStateReader, RejectedMessage, read_pose
from wholehand.ros2.messages import (
    BOOL,
    JOINT_STATE,
    POSE_STAMPED,
    MessageError,
    decode_bool,
    decode_joint_state,
    decode_pose,
)
from wholehand.ros2.transport import SampleMeta, TopicSubscriber, Transport

log = logging.getLogger(__name__)

HISTORY_SPACING = 0.001
"""Least time between two joint states handed to the controller's history [s]: a robot, or a
misconfigured node, sending thousands a second must not cost the control cycle per message,
nor shrink the time the history spans (the object pose's stamp is looked up in it)."""
DECODE_SPACING = 0.0005
"""Mean time between joint states decoded on arrival under a flood [s] (module docstring)."""
DECODE_BURST = 8.0
"""Joint states decoded on arrival back to back before :data:`DECODE_SPACING` applies."""
PENDING_MAX = 1024
"""Joint states kept for the history between two cycles at most (the oldest dropped first)."""

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Latest:
    """The newest good samples and when they arrived."""

    joint: JointSample | None
    previous: JointSample | None
    """The joint state before :attr:`joint` (velocities of states sent without them)."""
    joint_received: float
    """Receipt of :attr:`joint` [s, the streams' clock]; -inf before the first."""
    pose: tuple[FloatArray, float] | None
    """(4, 4) object pose in the world and its stamp [s]."""
    pose_received: float
    stop_requested: bool


class RobotStreams:
    """Subscribes the config's ``joint_states``, ``object_pose`` and ``stop`` topics on
    ``transport`` and keeps the newest good sample of each (module docstring), stamped on
    arrival by ``clock`` [s].

    Attributes:
        received: accepted messages per stream (``joint_states``, ``object_pose``).
        rejected: rejected messages per reason (``malformed``, ``not_finite``,
            ``unknown_joint``, ``old_stamp``, ``no_attachment``, ...).
        last_rejection: ``"<reason>: <detail>"`` of the latest rejection.
        stops: stop requests received (each true after a false or none).
    """

    def __init__(
        self,
        config: HardwareConfig,
        reader: JointStateReader,
        transport: Transport,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.config, self.reader, self.clock = config, reader, clock
        self.received: Counter[str] = Counter()
        self.rejected: Counter[str] = Counter()
        self.last_rejection = ""
        self.stops = 0
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        """Notified on every message, accepted or rejected."""
        self._pending: deque[JointSample] = deque(maxlen=PENDING_MAX)
        self._pending_stamp = -np.inf  # of the last joint state put in _pending
        self.arrived: Counter[str] = Counter()
        """Messages the transport delivered per stream, before any check."""
        self.superseded = 0
        """Joint states replaced by a newer one before they were decoded (a flood)."""
        self._deferred: tuple[bytes, float] | None = None  # (payload, receipt), not decoded
        self._tokens = DECODE_BURST  # decodes on arrival allowed now
        self._tokens_at = -np.inf  # when the tokens were counted
        self._joint: JointSample | None = None
        self._previous: JointSample | None = None
        self._joint_received = -np.inf
        self._pose: tuple[FloatArray, float] | None = None
        self._pose_received = -np.inf
        self._stop = False
        self._subs: list[TopicSubscriber] = [
            transport.subscriber("joint_states", JOINT_STATE, self._on_joints, self.reject),
            transport.subscriber("object_pose", POSE_STAMPED, self._on_pose, self.reject),
        ]
        if config.topic("stop"):
            self._subs.append(transport.subscriber("stop", BOOL, self._on_stop, self.reject))

    # --- the transport's threads ----------------------------------------------------------------
    def reject(self, reason: str, detail: str) -> None:
        """Count a dropped message (logged the first time of each reason)."""
        with self._changed:
            self.rejected[reason] += 1
            first = self.rejected[reason] == 1
            self.last_rejection = f"{reason}: {detail}"
            self._changed.notify_all()
        if first:
            log.warning("rejected a message (%s): %s", reason, detail)

    def _on_joints(self, payload: bytes, meta: SampleMeta, _: float) -> None:
        received = self.clock()
        with self._lock:
            self.arrived["joint_states"] += 1
            self.superseded += self._deferred is not None
            refill = (received - self._tokens_at) / DECODE_SPACING
            self._tokens = min(DECODE_BURST, self._tokens + refill)
            self._tokens_at = received
            if self._tokens < 1.0:
                self._deferred = (payload, received)
                return
            self._tokens -= 1.0
            self._deferred = None
        self._read_joints(payload, received)

    def _read_deferred(self) -> None:
        """Decode the joint state kept undecoded, if any (on the controller's thread)."""
        with self._lock:
            deferred, self._deferred = self._deferred, None
        if deferred is not None:
            self._read_joints(*deferred)

    def _read_joints(self, payload: bytes, received: float) -> None:
        """Decode, check and keep (or count) one joint state received at ``received``."""
        try:
            sample = self.reader.read(decode_joint_state(payload), time.time())
        except MessageError as err:
            self.reject("malformed", str(err))
            return
        except RejectedMessage as err:
            self.reject(err.reason, str(err))
            return
        with self._changed:
            self._changed.notify_all()
            if self._joint is not None and sample.stamp <= self._joint.stamp:
                self.rejected["old_stamp"] += 1
                return
            self._previous, self._joint = self._joint, sample
            self._joint_received = received
            if sample.stamp >= self._pending_stamp + HISTORY_SPACING:
                self._pending.append(sample)
                self._pending_stamp = sample.stamp
            self.received["joint_states"] += 1

    def _on_pose(self, payload: bytes, meta: SampleMeta, _: float) -> None:
        received = self.clock()
        self.arrived["object_pose"] += 1
        config = self.config
        try:
            msg = decode_pose(payload)
            wMo = read_pose(msg, config.frame_id, time.time(), config.safety.max_future_stamp)
        except MessageError as err:
            self.reject("malformed", str(err))
            return
        except RejectedMessage as err:
            self.reject(err.reason, str(err))
            return
        stamp = msg.stamp if config.stamp_source == "header" else time.time()
        with self._changed:
            self._changed.notify_all()
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
            self.reject("malformed", str(err))
            return
        with self._changed:
            self._changed.notify_all()
            if stop and not self._stop:
                self.stops += 1
                log.warning(
                    "stop requested on %s: arm frozen, hand ramping to zero",
                    self.config.topic("stop"),
                )
            self._stop = stop

    # --- the controller's thread ----------------------------------------------------------------
    @property
    def stop_requested(self) -> bool:
        """A stop message asked the robot to stop (until one that releases it)."""
        with self._lock:
            return self._stop

    def latest(self) -> Latest:
        """The newest samples, consistent with each other."""
        self._read_deferred()
        with self._lock:
            return Latest(
                self._joint,
                self._previous,
                self._joint_received,
                self._pose,
                self._pose_received,
                self._stop,
            )

    def take_pending(self) -> list[JointSample]:
        """The joint states accepted since the last call, oldest first, at least
        :data:`HISTORY_SPACING` apart (the newest accepted is :meth:`latest`'s)."""
        self._read_deferred()
        with self._lock:
            pending = list(self._pending)
            self._pending.clear()
        return pending

    def wait_for_first(self, timeout: float) -> None:
        """Block until a first joint state and a first object pose have arrived.

        Raises:
            ConfigError: one of them did not within ``timeout`` [s] (named, with what was
                rejected meanwhile and how the config reaches the robot).
        """
        if self.wait_until(lambda s: s._joint is not None and s._pose is not None, timeout):
            return
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

    def wait_until(self, condition: Callable[[RobotStreams], bool], timeout: float) -> bool:
        """Block until ``condition(self)`` holds, checked under the streams' lock at every
        message (accepted or rejected), at most ``timeout`` [s]; whether it holds."""
        with self._changed:
            return self._changed.wait_for(lambda: condition(self), timeout)

    def wait_for_fresh_joint(self, fresh_age: float, max_wait: float) -> tuple[str, float]:
        """If the newest joint state is older than ``fresh_age`` [s], wait up to ``max_wait``
        [s] for the next; returns how (``fresh``, ``waited``, ``timed_out``; ``none`` before
        a first joint state) and the time waited [s]. A joint state kept undecoded under a
        flood is decoded first: it is the newest."""
        self._read_deferred()
        with self._changed:
            received = self._joint_received
            started = self.clock()
            if self._joint is None:
                return "none", 0.0
            if started - received < fresh_age:
                return "fresh", 0.0
            arrived = self._changed.wait_for(
                lambda: self._joint_received != received, timeout=max_wait
            )
            return ("waited" if arrived else "timed_out"), self.clock() - started

    def close(self) -> None:
        for sub in self._subs:
            sub.close()
        self._subs.clear()
