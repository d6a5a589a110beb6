"""``wholehand hw-sim`` on an arm-hand: the robot double plays the whole reach episode.

The scene of ``wholehand reach`` with the same seed (:func:`~wholehand.reaching.episode.
episode_scene`: the arm at home, the person holding the object out) runs in MuJoCo in real time.
The arm is behind a position controller (the newest target of the arm topic, held, tracked by
the arm's PD law with gravity feed-forward, as ros2_control's forward command controller on a
position interface and the arm's drives do), the hand behind a torque controller
(:class:`~wholehand.doubles.double.RemoteTorque`). The person of ``wholehand reach`` moves the
object while the hand reaches, lets go once it is held, pushes and twists it, and snatches it
away. The person judges that the hand holds the object as in process, by the controller's stage
(``regulate``), which the controller publishes on its status topic; from a controller that
publishes none, by the simulated contacts (the thumb and two other fingers touching). With
``away`` the
person instead carries the object out of the arm's workspace and back, for the home rule.

Joint states (arm and hand) go out at the joint-state rate, the tracked pose at the tracker's
rate with its latency, noise and dropouts, as in :mod:`wholehand.doubles.double`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from wholehand.backends.command import Command, JointTargets
from wholehand.doubles.double import (
    DOUBLE_NODE,
    RealTimePacer,
    RemoteTorque,
    RobotPublisher,
    check_gaps,
    wait_for_command,
)
from wholehand.errors import ConfigError
from wholehand.loop.control_loop import ControlLoop, Cycle, Observer
from wholehand.loop.stage import CycleContext, Stage, StageOutput
from wholehand.models.hand import HandModel
from wholehand.reaching.episode import episode_scene
from wholehand.reaching.episode_spec import EpisodeSpec
from wholehand.reaching.person import PERTURBATIONS, ContactHolds, Event, Person, grip
from wholehand.reaching.stages import FINGER_KD, FINGER_KP, REGULATE, ArmServo
from wholehand.robot.stopping import StopOnEvent, signals_set
from wholehand.ros2.config import HardwareConfig
from wholehand.ros2.inputs import JointStateReader, arm_command_dofs, command_dofs
from wholehand.ros2.messages import (
    FLOAT64_ARRAY,
    JOINT_STATE,
    JOINT_TRAJECTORY,
    POSE_STAMPED,
    STRING,
    MessageError,
    decode_array,
    decode_joint_trajectory,
    decode_string,
)
from wholehand.ros2.node import open_transport
from wholehand.ros2.transport import SampleMeta
from wholehand.trials.trial import tracking_filters

FloatArray = npt.NDArray[np.float64]

AWAY_OFFSET = (0.0, 0.6, 0.0)
"""Where the person carries the object with ``away``, from where it is held [m]."""
AWAY_SPEED = 0.5
"""How fast the person carries it there and back [m/s]."""


@dataclass(frozen=True)
class EpisodeDoubleSpec:
    """The episode the double plays and how its streams behave."""

    episode: EpisodeSpec = field(
        default_factory=lambda: EpisodeSpec(hand="flexiv_rizon4_hx5_d20_right")
    )
    latency: float = 0.033
    """Pose latency: image time to publication [s]."""
    noise_mm: float = 0.0
    noise_deg: float = 0.0
    dropouts: tuple[tuple[float, float], ...] = ()
    """``(start, duration)`` [s] without poses."""
    joint_gaps: tuple[tuple[float, float], ...] = ()
    """``(start, duration)`` [s] without joint states (the robot's driver stalls)."""
    command_timeout: float = 0.1
    """The hand's drives hold the last torque this long [s], then apply zero."""
    away: tuple[float, float] | None = None
    """``(start, duration)`` [s]: the person carries the object out of the workspace at
    ``start`` and back after ``duration`` (instead of the episode's perturbations)."""

    def __post_init__(self) -> None:
        if not (np.isfinite(self.latency) and self.latency >= 0.0):
            raise ConfigError(f"hw-sim: latency must be >= 0 [s], got {self.latency!r}")
        if not (np.isfinite(self.command_timeout) and self.command_timeout > 0.0):
            raise ConfigError("hw-sim: command_timeout must be > 0 [s]")
        check_gaps(self.joint_gaps)
        if self.away is not None and not (self.away[0] >= 0.0 and self.away[1] > 0.0):
            raise ConfigError(
                f"hw-sim: away needs a start >= 0 and a duration > 0 [s], got {self.away}"
            )


class RemoteArmHand(Stage):
    """The robot's controllers: the hand's torques (:class:`RemoteTorque`) and the arm's newest
    position target, held (before any: where the arm started), servoed with the arm's gains and
    its gravity feed-forward. With a hand position topic, the hand's driver switches to position
    control (the finger servo's gains) while its newest command is a position one.

    Statuses: those of :class:`RemoteTorque`, and ``remote_position`` for a hand under position
    control.
    """

    name = "drives"
    needs_object_pose = False

    def __init__(
        self, hand: HandModel, config: HardwareConfig, timeout: float, q0: FloatArray
    ) -> None:
        self.hand = hand
        self.trajectory = config.arm.interface == "trajectory"
        self.torque = RemoteTorque(hand, command_dofs(hand, config), timeout)
        self.arm = ArmServo(hand)
        self.arm_dofs = arm_command_dofs(hand, config)
        """(n_arm,) velocity indices of the arm command's joints, in its order."""
        reader = JointStateReader(hand, config)
        self.arm_names = tuple(reader.msg_name[hand.joint_names[i]] for i in self.arm_dofs)
        self.target = np.asarray(q0, dtype=float)[self.arm_dofs].copy()
        self.hand_target: tuple[FloatArray, float] | None = None
        """The newest hand position command (command order) and when it arrived [s]."""
        self.hand_position_messages = 0
        self.arm_messages = 0
        self.malformed_arm = 0
        self._lock = threading.Lock()

    def on_arm(self, payload: bytes, meta: SampleMeta, received: float) -> None:
        """A Float64MultiArray or JointTrajectory of arm positions (the controller's order)."""
        try:
            if self.trajectory:
                names, data = decode_joint_trajectory(payload)
                if names != self.arm_names:
                    raise MessageError(f"trajectory joints {names} are not {self.arm_names}")
            else:
                data = decode_array(payload)
        except MessageError:
            self.malformed_arm += 1
            return
        if data.shape != self.arm_dofs.shape or not np.isfinite(data).all():
            self.malformed_arm += 1
            return
        with self._lock:
            self.target = data
            self.arm_messages += 1

    def commanded(self) -> bool:
        """A first command (torque or hand position) has arrived."""
        return self.torque.received > 0 or self.hand_position_messages > 0

    def on_hand_position(self, payload: bytes, meta: SampleMeta, received: float) -> None:
        """A Float64MultiArray of hand positions in the torque command's joint order."""
        try:
            data = decode_array(payload)
        except MessageError:
            self.malformed_arm += 1
            return
        if data.shape != self.torque.dofs.shape or not np.isfinite(data).all():
            self.malformed_arm += 1
            return
        with self._lock:
            self.hand_target = (data, received)
            self.hand_position_messages += 1

    def step(self, context: CycleContext) -> StageOutput:
        out = self.torque.step(context)
        assert out.command is not None
        tau = out.command.tau.copy()
        obs = context.obs
        tau[self.arm.dofs] = self.arm.feedforward(obs.q, obs.wMb)
        with self._lock:
            target, hand = self.target.copy(), self.hand_target
        kp, kd = np.full(target.size, self.arm.kp), np.full(target.size, self.arm.kd)
        groups = [JointTargets(self.arm_dofs, target, None, kp, kd, name="arm")]
        latest = self.torque.latest
        status = out.status
        if hand is not None and (latest is None or hand[1] > latest[1]):
            dofs = self.torque.dofs
            tau[dofs] = 0.0
            kp_hand, kd_hand = np.full(dofs.size, FINGER_KP), np.full(dofs.size, FINGER_KD)
            groups.append(JointTargets(dofs, hand[0], None, kp_hand, kd_hand, name="hand"))
            status = "remote_position"
        return StageOutput(Command(tau, tuple(groups)), status)


class ControllerHolds:
    """The person's view of a grasp as in process: the hand holds the object while the
    controller's status topic says it regulates (``std_msgs/msg/String``, the stage's name);
    until a first status arrives (a controller that publishes none), the ``contacts`` decide."""

    def __init__(self, contacts: Callable[[Cycle], bool]) -> None:
        self.contacts = contacts
        self.stage: str | None = None
        """The controller's newest stage; None before its first status message."""
        self.messages = 0
        self.malformed = 0
        self._lock = threading.Lock()

    def on_status(self, payload: bytes, meta: SampleMeta, received: float) -> None:
        """A status message (the transport's thread)."""
        try:
            stage = decode_string(payload)
        except MessageError:
            self.malformed += 1
            return
        with self._lock:
            self.stage = stage
            self.messages += 1

    def __call__(self, cycle: Cycle) -> bool:
        with self._lock:
            stage = self.stage
        return self.contacts(cycle) if stage is None else stage == REGULATE


class CarryAway(Observer):
    """The person holds the object out, carries it out of the arm's workspace at ``start``, and
    back to where it was held after ``duration`` [s]; then holds it there."""

    def __init__(
        self,
        backend: Any,
        wMo_hold: FloatArray,
        mass_inertia: tuple[float, float],
        start: float,
        duration: float,
    ) -> None:
        self.backend, self.wMo_hold = backend, wMo_hold
        self.mass_inertia = mass_inertia
        self.start, self.duration = start, duration
        self.events: list[Event] = []
        self._away = wMo_hold.copy()
        self._away[:3, 3] += AWAY_OFFSET

    def on_start(self, loop: ControlLoop) -> None:
        grip(self.backend, self.wMo_hold, self.mass_inertia)

    def on_cycle(self, cycle: Cycle) -> str | None:
        t = cycle.t - self.start
        if t < 0.0:
            return None
        travel = float(np.linalg.norm(AWAY_OFFSET)) / AWAY_SPEED
        out = min(t, travel) if t < self.duration else max(0.0, travel - (t - self.duration))
        target = self.wMo_hold.copy()
        target[:3, 3] += (out / travel) * np.asarray(AWAY_OFFSET)
        grip(self.backend, target, self.mass_inertia)
        if not self.events:
            self.events.append(Event(round(cycle.t, 4), "person carries the object away"))
        elif len(self.events) == 1 and t >= self.duration:
            self.events.append(Event(round(cycle.t, 4), "person brings the object back"))
        return None


def run_episode_double(
    spec: EpisodeDoubleSpec,
    config: HardwareConfig,
    wait_for_controller: float = 30.0,
    observers: Sequence[Observer] = (),
    announce: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Play the robot through the episode of ``spec``: wait for the first torque command, then
    run in real time until the person's script ends or ``episode.duration`` has passed. SIGINT
    and SIGTERM end the wait or the run early (``interrupted`` in the summary); ``announce``
    gets a line when the double starts waiting.

    Returns:
        A JSON-ready summary: ``complete``, the person's ``events`` (times from the start of the
        run, which lies at ``start_monotonic_s`` on this machine's monotonic clock: the
        controller's transitions are on it too), ``perturbations``, the statuses of the drives,
        message counts, ``late_cycles``, MuJoCo's warnings.

    Raises:
        ConfigError: no torque command within ``wait_for_controller`` [s]; a hand without an arm
            or a config without an arm topic.
    """
    if not config.topic("arm_command"):
        raise ConfigError(
            f"{config.path or 'hardware config'}: the episode double plays an arm: set [topics] "
            "arm_command and [arm] joints"
        )
    scene = episode_scene(spec.episode)
    hand, obj, backend = scene.hand, scene.obj, scene.backend
    if not hand.arm_dofs.any():
        raise ConfigError(
            f"hw-sim: {hand.name!r} has no arm; the episode double plays an arm-hand assembly"
        )
    first = backend.observe()
    drives = RemoteArmHand(hand, config, spec.command_timeout, first.q)
    inertia = float(np.linalg.eigvalsh(np.asarray(obj.inertia)).max())
    mass_inertia = (obj.mass, inertia)
    rim = 0.5 * float(np.max(obj.extents))
    script: Person | CarryAway
    holds = ControllerHolds(ContactHolds(hand, backend))
    if spec.away is None:
        script = Person(
            spec.episode,
            backend,
            scene.wMo,
            scene.rng,
            mass_inertia,
            hand.palm_link,
            rim,
            scene.on_table,
            holds=holds,
        )
    else:
        script = CarryAway(backend, scene.wMo, mass_inertia, *spec.away)
    reader = JointStateReader(hand, config)
    names = [reader.msg_name[j] for j in hand.joint_names]
    tracking: dict[str, Any] = {"rate_hz": config.object_pose_rate, "latency_s": spec.latency}
    if spec.noise_mm or spec.noise_deg:
        tracking.update(
            noise_mm=spec.noise_mm, noise_deg=spec.noise_deg, noise_seed=spec.episode.seed
        )
    if spec.dropouts:
        tracking["dropouts"] = [list(d) for d in spec.dropouts]
    arm_type = JOINT_TRAJECTORY if config.arm.interface == "trajectory" else FLOAT64_ARRAY
    transport = open_transport(config, DOUBLE_NODE)
    try:
        joints = transport.publisher("joint_states", JOINT_STATE)
        poses = transport.publisher("object_pose", POSE_STAMPED)
        torque = drives.torque
        subs = [
            transport.subscriber(
                "torque_command", FLOAT64_ARRAY, torque.on_message, torque.on_rejected
            ),
            transport.subscriber("arm_command", arm_type, drives.on_arm),
        ]
        if config.topic("hand_position_command"):
            topic = "hand_position_command"
            subs.append(transport.subscriber(topic, FLOAT64_ARRAY, drives.on_hand_position))
        if config.topic("status"):
            subs.append(transport.subscriber("status", STRING, holds.on_status))
        publisher = RobotPublisher(joints, poses, names, config.frame_id, "image", spec.joint_gaps)
        pacer = RealTimePacer()
        stopped = threading.Event()  # Ctrl-C or SIGTERM: the run ends and its summary is written
        loop = ControlLoop(
            backend,
            hand,
            obj,
            drives,
            rate=config.joint_state_rate,
            filters=tracking_filters(tracking, obj.com),
            observers=[script, publisher, *observers, pacer, StopOnEvent(stopped)],
        )
        commanded = lambda: drives.commanded() or stopped.is_set()  # noqa: E731
        with signals_set(stopped):
            if announce is not None:
                announce(
                    f"hw-sim: playing {hand.name}'s episode, waiting for a controller's first "
                    "command (Ctrl-C stops)"
                )
            wait_for_command(backend, commanded, joints, poses, names, config, wait_for_controller)
            report = loop.run(0.0 if stopped.is_set() else spec.episode.duration)
        wall = time.monotonic() - pacer.mono0  # the run's simulated time took this long
        for sub in subs:
            sub.close()
    finally:
        transport.close()
    events = [asdict(e) for e in script.events]
    return {
        "spec": {**asdict(spec.episode), "latency": spec.latency, "away": spec.away},
        "interrupted": stopped.is_set(),
        "complete": bool(getattr(script, "complete", False)),
        "skipped_perturbations": list(getattr(script, "skipped", [])),
        "events": events,
        "perturbations": sum(e["what"].startswith(PERTURBATIONS) for e in events),
        "duration_s": backend.time,
        "start_monotonic_s": pacer.mono0,
        "wall_s": wall,
        "cycles": report.cycles,
        "statuses": dict(report.status_counts),
        "late_cycles": pacer.late,
        "torque_messages": drives.torque.received,
        "malformed_commands": drives.torque.malformed + drives.malformed_arm,
        "arm_messages": drives.arm_messages,
        "hand_position_messages": drives.hand_position_messages,
        "status_messages": holds.messages,
        "pose_messages": publisher.pose_messages,
        "joint_states_withheld": publisher.joint_states_withheld,
        "max_torque_rate_Nm_s": drives.torque.max_rate,
        "stops_to_zero": drives.torque.stops,
        "sim_warnings": backend.warnings(),
    }
