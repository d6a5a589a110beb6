"""``wholehand hw-sim``: a test double that plays the robot over the hardware path's messages.

MuJoCo runs in real time at a stored grasp. Each cycle of the double (at the joint-state rate) it
publishes the joint state (positions, velocities and the efforts the drives apply, stamped with
the sample's wall time); a tracker publishes the object pose at its rate with a latency, noise and
dropouts (the loop's observation filters, :mod:`wholehand.loop.filters`), stamped with the image
time or the processing time; torque commands are applied as they arrive, held like a drive holds
its last command, and dropped to zero after ``command_timeout``. The perturbation protocol and the
grasp-loss check run on the simulated object, so the double reports whether the grasp held.

It is a stand-in for a robot, not part of the controller: it shares only the messages, config
and models with ``wholehand control``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from wholehand import registry
from wholehand.backends.command import Command
from wholehand.backends.observation import check_observation
from wholehand.errors import ConfigError
from wholehand.grasps.store import load_grasps
from wholehand.loop.control_loop import ControlLoop, Cycle, Observer
from wholehand.loop.grasp_loss import GraspLossMonitor
from wholehand.loop.record import Recorder, RunRecord
from wholehand.loop.stage import CycleContext, Stage, StageOutput
from wholehand.models.hand import HandModel, load_hand
from wholehand.models.kinematics import HandKinematics
from wholehand.models.object_catalogue import load_object
from wholehand.models.objects import ObjectModel
from wholehand.robot.stopping import StopOnEvent, signals_set
from wholehand.ros2.config import HardwareConfig
from wholehand.ros2.inputs import JointStateReader, command_dofs
from wholehand.ros2.messages import (
    FLOAT64_ARRAY,
    JOINT_STATE,
    POSE_STAMPED,
    MessageError,
    decode_array,
    encode_joint_state,
    encode_pose,
)
from wholehand.ros2.node import open_transport
from wholehand.ros2.transport import SampleMeta, TopicPublisher
from wholehand.trials.protocol import PerturbationProtocol, ProtocolDriver
from wholehand.trials.trial import tracking_filters

FloatArray = npt.NDArray[np.float64]

DOUBLE_NODE = "wholehand_hw_sim"
"""The double's node name in the ROS 2 graph."""

POSE_STAMPS = ("image", "processing")
"""What the double's tracker stamps a pose with: the image time (correct) or the time it
finished processing the image (the image time plus the latency: a common tracker bug)."""


@dataclass(frozen=True)
class DoubleSpec:
    """What the double simulates and how its streams behave."""

    hand: str = "allegro_right"
    object: str = "077_rubiks_cube"
    grasp: int = 0
    theta_deg: float = 0.0
    """The protocol's pull [deg]; 0: the load test only."""
    seed: int = 0
    latency: float = 0.033
    """Pose latency: image time to publication [s]."""
    noise_mm: float = 0.0
    noise_deg: float = 0.0
    dropouts: tuple[tuple[float, float], ...] = ()
    """``(start, duration)`` [s] of protocol time without poses."""
    joint_gaps: tuple[tuple[float, float], ...] = ()
    """``(start, duration)`` [s] of protocol time without joint states (the robot's driver
    stalls; the simulation goes on)."""
    pose_stamp: str = "image"
    command_timeout: float = 0.1
    """The drives hold the last torque this long [s], then apply zero."""
    gravity: bool = False
    protocol_params: dict[str, Any] = field(default_factory=dict)
    timestep: float = 0.001

    def __post_init__(self) -> None:
        if self.pose_stamp not in POSE_STAMPS:
            raise ConfigError(f"hw-sim: pose_stamp must be one of {POSE_STAMPS}")
        if not (np.isfinite(self.latency) and self.latency >= 0.0):
            raise ConfigError(f"hw-sim: latency must be >= 0 [s], got {self.latency!r}")
        if not (np.isfinite(self.command_timeout) and self.command_timeout > 0.0):
            raise ConfigError("hw-sim: command_timeout must be > 0 [s]")
        check_gaps(self.joint_gaps)


def check_gaps(gaps: tuple[tuple[float, float], ...]) -> None:
    """Raise ConfigError unless every ``(start, duration)`` has a start >= 0 and a duration > 0
    [s]."""
    for start, duration in gaps:
        if not (np.isfinite(start) and start >= 0.0 and np.isfinite(duration) and duration > 0.0):
            raise ConfigError(
                f"hw-sim: a joint-state gap needs START >= 0 and DURATION > 0 [s], got "
                f"{start} {duration}"
            )


class RemoteTorque(Stage):
    """The drives: the newest torque command received, held for ``timeout`` [s], then zero.

    Statuses: ``remote`` (a fresh command), ``no_command`` (none yet), ``command_timeout``.
    """

    name = "drives"
    needs_object_pose = False

    def __init__(self, hand: HandModel, command_dofs: npt.NDArray[np.intp], timeout: float):
        self.nv, self.dofs, self.timeout = hand.nv, command_dofs, timeout
        self.tau_max = np.where(hand.actuated_dofs, hand.tau_max, 0.0)
        self._latest: tuple[FloatArray, float] | None = None
        self._lock = threading.Lock()
        self.received = 0
        self.malformed = 0
        self.arrivals: list[tuple[int, int]] = []
        """(source timestamp [ns], arrival wall time [ns]) of every torque message."""
        self.max_rate = 0.0
        """Largest torque rate between consecutive commands of one controller [N*m/s], by the
        publish stamps of their attachments; a step to zero torque on every joint (a safety
        stop, e.g. the guard's ``joints_stale``) is counted in :attr:`stops` instead."""
        self.stops = 0
        """Steps of one controller to zero torque on every joint from a nonzero torque."""
        self.restart_steps: list[float] = []
        """For each controller after the first (a new publisher GID): the largest difference
        between its first command and the torque the drives applied when it arrived [N*m]."""
        self._source: tuple[bytes, int] | None = None

    def on_message(self, payload: bytes, meta: SampleMeta, received: float) -> None:
        arrival = time.time_ns()
        try:
            data = decode_array(payload)
        except MessageError:
            self.malformed += 1
            return
        if data.shape != self.dofs.shape or not np.isfinite(data).all():
            self.malformed += 1
            return
        tau = np.zeros(self.nv)
        tau[self.dofs] = data
        tau = np.clip(tau, -self.tau_max, self.tau_max)
        with self._lock:
            applied = self._applied(received)
            if self._source is not None and self._source[0] == meta.source:
                dt = 1e-9 * (meta.source_timestamp - self._source[1])
                if not tau.any() and applied.any():
                    self.stops += 1
                elif dt > 0.0:
                    self.max_rate = max(self.max_rate, float(np.abs(tau - applied).max()) / dt)
            elif self._source is not None:
                self.restart_steps.append(float(np.abs(tau - applied).max()))
            self._source = (meta.source, meta.source_timestamp)
            self._latest = (tau, received)
            self.received += 1
            self.arrivals.append((meta.source_timestamp, arrival))

    def on_rejected(self, reason: str, detail: str) -> None:
        """A torque sample the transport dropped counts as malformed."""
        self.malformed += 1

    @property
    def latest(self) -> tuple[FloatArray, float] | None:
        """The newest torque command (model order [N*m]) and when it arrived [s, monotonic]."""
        with self._lock:
            return self._latest

    def _applied(self, now: float) -> FloatArray:
        """The torque the drives apply at ``now`` (monotonic [s])."""
        latest = self._latest
        if latest is None or now - latest[1] > self.timeout:
            return np.zeros(self.nv)
        return latest[0]

    def step(self, context: CycleContext) -> StageOutput:
        with self._lock:
            latest = self._latest
            applied = self._applied(time.monotonic())
        if latest is None:
            return StageOutput(Command.torques(applied), "no_command")
        if applied is not latest[0]:
            return StageOutput(Command.torques(applied), "command_timeout")
        return StageOutput(Command.torques(applied), "remote")


class RobotPublisher(Observer):
    """Publishes each cycle's joint state and each new tracked pose, stamped in wall time.

    The joint state's effort is the torque the motors applied in the last simulation step
    (the backend's ``applied_torques()``, where it has one): under a position command that is
    the servo's torque, not the zero torque command, as a drive reports it. No joint state goes
    out during the ``joint_gaps`` (``(start, duration)`` [s] of simulation time); they are
    counted in :attr:`joint_states_withheld`."""

    def __init__(
        self,
        joints: TopicPublisher,
        poses: TopicPublisher,
        names: list[str],
        frame_id: str,
        pose_stamp: str,
        joint_gaps: tuple[tuple[float, float], ...] = (),
    ) -> None:
        self.joints, self.poses, self.names = joints, poses, names
        self.frame_id, self.pose_stamp = frame_id, pose_stamp
        self.joint_gaps = joint_gaps
        self.wall0 = 0.0
        self._published = np.nan
        self.pose_messages = 0
        self.joint_states_withheld = 0
        self._applied: Callable[[], FloatArray] | None = None

    def on_start(self, loop: ControlLoop) -> None:
        self.wall0 = time.time() - loop.backend.time
        self._applied = getattr(loop.backend, "applied_torques", None)

    def on_cycle(self, cycle: Cycle) -> str | None:
        truth, seen = cycle.truth, cycle.context.obs
        if any(start <= cycle.t < start + length for start, length in self.joint_gaps):
            self.joint_states_withheld += 1
        else:
            effort = cycle.command.tau if self._applied is None else self._applied()
            stamp = self.wall0 + truth.stamp_q
            self.joints.put(encode_joint_state(stamp, self.names, truth.q, truth.dq, effort))
        if seen.wMo is not None and seen.stamp_object != self._published:
            self._published = seen.stamp_object
            t = seen.stamp_object if self.pose_stamp == "image" else cycle.t
            self.poses.put(encode_pose(self.wall0 + t, self.frame_id, seen.wMo))
            self.pose_messages += 1
        return None


class RealTimePacer(Observer):
    """Holds the simulation to the wall clock: each cycle ends no earlier than its wall time.

    Attributes:
        late: cycles that started after their wall time (the simulation fell behind).
    """

    def __init__(self) -> None:
        self.mono0 = 0.0
        """``time.monotonic()`` at backend time 0 [s]: where the run's times lie on the
        machine's monotonic clock."""
        self._dt = 0.0
        self.late = 0

    def on_start(self, loop: ControlLoop) -> None:
        self.mono0 = time.monotonic() - loop.backend.time
        self._dt = loop.dt

    def on_cycle(self, cycle: Cycle) -> str | None:
        wait = self.mono0 + cycle.t + self._dt - time.monotonic()
        if wait > 0.0:
            time.sleep(wait)
        elif wait < -self._dt:
            self.late += 1
        return None


def run_double(
    spec: DoubleSpec,
    config: HardwareConfig,
    wait_for_controller: float = 30.0,
    hand: HandModel | None = None,
    obj: ObjectModel | None = None,
    observers: Sequence[Observer] = (),
    announce: Callable[[str], None] | None = None,
) -> tuple[dict[str, Any], RunRecord]:
    """Play the robot: wait for the first torque command, then run the protocol in real time.
    SIGINT and SIGTERM end the wait or the run early (``interrupted`` in the summary);
    ``announce`` gets a line when the double starts waiting.

    Returns:
        A JSON-ready summary (``held``, ``lost_at``, message counts, ``max_torque_step``,
        ``arrivals`` of the torque messages) and the run's record.

    Raises:
        ConfigError: no torque command within ``wait_for_controller`` [s], or a bad spec.
    """
    hand = hand or load_hand(spec.hand)
    obj = obj or load_object(spec.object)
    grasps = load_grasps(spec.hand, spec.object, "power")
    if not 0 <= spec.grasp < len(grasps):
        raise ConfigError(f"hw-sim: grasp {spec.grasp} does not exist ({len(grasps)} stored)")
    grasp = grasps[spec.grasp]
    backend = registry.load(
        "backends",
        "mujoco",
        hand=hand,
        obj=obj,
        q_init=grasp.q_array(hand),
        wMo_init=grasp.object_pose(hand.wMb),
        gravity=spec.gravity,
        timestep=spec.timestep,
    )
    reader = JointStateReader(hand, config)
    names = [reader.msg_name[j] for j in hand.joint_names]
    drives = RemoteTorque(hand, command_dofs(hand, config), spec.command_timeout)
    protocol = PerturbationProtocol(
        theta_deg=spec.theta_deg, seed=spec.seed, **spec.protocol_params
    )
    rate = config.joint_state_rate
    protocol.check_rate(rate)
    transport = open_transport(config, DOUBLE_NODE)
    try:
        joints = transport.publisher("joint_states", JOINT_STATE)
        poses = transport.publisher("object_pose", POSE_STAMPED)
        commands = transport.subscriber(
            "torque_command", FLOAT64_ARRAY, drives.on_message, drives.on_rejected
        )
        publisher = RobotPublisher(
            joints, poses, names, config.frame_id, spec.pose_stamp, spec.joint_gaps
        )
        driver = ProtocolDriver(protocol, obj)
        loss = GraspLossMonitor(hand, obj, stop_on_loss=False)
        recorder = Recorder(loss, driver, {"hw_sim": spec.__dict__})
        pacer = RealTimePacer()
        stopped = threading.Event()  # Ctrl-C or SIGTERM: the run ends and its summary is written
        tracking: dict[str, Any] = {"rate_hz": config.object_pose_rate, "latency_s": spec.latency}
        if spec.noise_mm or spec.noise_deg:
            tracking.update(noise_mm=spec.noise_mm, noise_deg=spec.noise_deg, noise_seed=spec.seed)
        if spec.dropouts:
            tracking["dropouts"] = [list(d) for d in spec.dropouts]
        loop = ControlLoop(
            backend,
            hand,
            obj,
            drives,
            rate=rate,
            filters=tracking_filters(tracking, obj.com),
            observers=[driver, loss, recorder, publisher, *observers, pacer, StopOnEvent(stopped)],
        )
        # Everything is built and the compiled checks loaded (~0.2 s on their first call)
        # before the wait: the streams go on without a gap when it ends.
        first, kinematics = backend.observe(), HandKinematics(hand)
        check_observation(first, hand.nq, hand.nv)
        kinematics.update(first.q, first.wMb)
        assert first.wMo is not None
        loss.check.held(kinematics, first.wMo)
        commanded = lambda: drives.received > 0 or stopped.is_set()  # noqa: E731
        with signals_set(stopped):
            if announce is not None:
                announce(
                    f"hw-sim: publishing {hand.name}'s state, waiting for a controller's first "
                    "command (Ctrl-C stops)"
                )
            wait_for_command(backend, commanded, joints, poses, names, config, wait_for_controller)
            run_start = time.time_ns()
            report = loop.run(0.0 if stopped.is_set() else protocol.duration)
            run_end = time.time_ns()
        commands.close()
    finally:
        transport.close()
    statuses = dict(report.status_counts)
    summary = {
        "interrupted": stopped.is_set(),
        "held": loss.lost_at is None,
        "lost_at": loss.lost_at,
        "cycles": report.cycles,
        "statuses": statuses,
        "late_cycles": pacer.late,
        "torque_messages": drives.received,
        "malformed_commands": drives.malformed,
        "pose_messages": publisher.pose_messages,
        "joint_states_withheld": publisher.joint_states_withheld,
        "max_torque_rate_Nm_s": drives.max_rate,
        "stops_to_zero": drives.stops,
        "restart_steps_Nm": drives.restart_steps,
        "sim_warnings": backend.warnings(),
        "arrivals": drives.arrivals,
        "run_wall_ns": [run_start, run_end],
    }
    return summary, recorder.record


def wait_for_command(
    backend: Any,
    commanded: Callable[[], bool],
    joints: TopicPublisher,
    poses: TopicPublisher,
    names: list[str],
    config: HardwareConfig,
    timeout: float,
) -> None:
    """Publish the resting state (frozen) at the streams' rates until ``commanded()`` says a
    first command arrived."""
    obs = backend.observe()
    start = time.monotonic()
    next_pose = start
    while not commanded():
        now = time.monotonic()
        if now - start > timeout:
            raise ConfigError(
                f"hw-sim: no command on {config.topics['torque_command']!r} within "
                f"{timeout:g} s; start `wholehand control` with the same config and endpoints"
            )
        stamp = time.time()
        joints.put(encode_joint_state(stamp, names, obs.q, obs.dq, np.zeros(len(names))))
        if now >= next_pose:
            poses.put(encode_pose(stamp, config.frame_id, obs.wMo))
            next_pose += 1.0 / config.object_pose_rate
        time.sleep(1.0 / config.joint_state_rate)
