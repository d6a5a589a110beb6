"""The hardware config's types: topics, joint names, rates, QoS and safety limits of a ROS 2
robot. Its TOML file, its schema and its checks are :mod:`wholehand.ros2.config_file`."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

from wholehand.errors import ConfigError
from wholehand.reaching.workspace import Workspace

Reliability = Literal["reliable", "best_effort"]
History = Literal["keep_last", "keep_all"]
StampSource = Literal["header", "receipt"]
ArmInterface = Literal["position", "trajectory"]

DISTROS = ("humble", "jazzy", "kilted")
"""ROS 2 distributions whose names, type hashes and graph messages we write."""
TRANSPORTS = ("zenoh", "dds")
"""How messages travel: as rmw_zenoh, or as ROS 2's DDS middlewares."""

TOPICS = (
    "joint_states", "object_pose", "torque_command", "arm_command", "hand_position_command",
    "stop", "status",
)  # fmt: skip
STAMP_SOURCES: tuple[StampSource, ...] = ("header", "receipt")


@dataclass(frozen=True)
class QoS:
    """The part of a ROS 2 QoS profile rmw_zenoh maps onto zenoh."""

    reliability: Reliability = "reliable"
    history: History = "keep_last"
    depth: int = 1


@dataclass(frozen=True)
class SafetyLimits:
    """The safety rules' times and rates (see :mod:`wholehand.robot.guard`)."""

    joint_timeout: float = 0.05
    """A joint state older than this [s]: the loop's torque is not sent, the last one is held
    (``joints_late``)."""
    joint_hold: float = 0.1
    """How long past ``joint_timeout`` the torque is held [s]; then it ramps linearly to zero
    over ``joint_ramp`` (``joints_stale``). Within the two a held grasp survives a gap in the
    joint states (a busy computer, a lost message)."""
    joint_ramp: float = 0.25
    """Duration of that ramp [s]; past ``joint_timeout + joint_hold + joint_ramp``, and while no
    joint state has come at all, zero torque (``joints_lost``)."""
    pose_timeout: float = 0.2
    """An object pose older than this [s] -> the last torque held, then ramped to zero."""
    pose_ramp: float = 0.5
    """Duration of the ramp to zero after a pose timeout [s]."""
    torque_rate: float = 20.0
    """Largest change of any joint's torque command per second [N*m/s]; a restarted controller
    starts from the measured effort and cannot jump past it."""
    watchdog: float = 0.05
    """No command from the loop for this long [s] -> the watchdog ramps the torque down."""
    max_future_stamp: float = 0.01
    """A message stamped further than this [s] ahead of the controller's clock is rejected."""
    exit_ramp: float = 0.5
    """On every exit of the controller (its end, Ctrl-C, SIGTERM, a fault of the loop) the hand
    torques ramp to zero over this time [s] while the arm holds its position."""

    def __post_init__(self) -> None:
        if not self.joint_hold >= 0.0:
            raise ConfigError(f"[safety] joint_hold must be a time >= 0 [s], got {self.joint_hold}")
        if not self.joint_ramp > 0.0:
            raise ConfigError(f"[safety] joint_ramp must be a time > 0 [s], got {self.joint_ramp}")


@dataclass(frozen=True)
class ArmSettings:
    """How the controller commands an arm (the ``[arm]`` table)."""

    joints: tuple[str, ...] = ()
    """The arm controller's joints in the order of its command (ros2_control's ``joints``)."""
    interface: ArmInterface = "position"
    """``position``: ``std_msgs/msg/Float64MultiArray`` for ``ForwardCommandController`` with
    ``interface_name: position``; ``trajectory``: ``trajectory_msgs/msg/JointTrajectory`` (one
    point, one control period ahead) for ``joint_trajectory_controller``."""
    velocity_scale: float = 0.5
    """Targets move at most this fraction of the URDF's joint velocity limits [-]."""
    home: tuple[float, ...] | None = None
    """Home posture of the arm joints [rad] in the order of ``joints`` (None: the assembly's
    ``[assembly] home``)."""


@dataclass(frozen=True)
class HardwareConfig:
    """Topics, joint names, rates, QoS and safety limits of a ROS 2 robot (the module's
    schema). ``path`` is the file it came from ("" for the defaults)."""

    transport: str = "zenoh"
    """``"zenoh"`` (:mod:`wholehand.ros2.rmw_zenoh`) or ``"dds"``
    (:mod:`wholehand.ros2.ros2_dds`)."""
    domain_id: int = 0
    distro: str = "jazzy"
    mode: str = "peer"
    connect: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    listen: tuple[str, ...] = ()
    dds_interface: str = ""
    """DDS: the network interface (name or address) to use; "" for Cyclone DDS's choice."""
    dds_peers: tuple[str, ...] = ()
    """DDS: unicast discovery peers (multicast off); () for multicast discovery."""
    topics: dict[str, str] = field(
        default_factory=lambda: {
            "joint_states": "/joint_states",
            "object_pose": "/object_pose",
            "torque_command": "/hand_effort_controller/commands",
            "arm_command": "",
            "hand_position_command": "",
            "stop": "/wholehand/stop",
            "status": "/wholehand/status",
        }
    )
    rename: dict[str, str] = field(default_factory=dict)
    ignore: tuple[str, ...] = ()
    command_joints: tuple[str, ...] | None = None
    """The torque command's joints in its order (``[joints] command``; required in a file)."""
    arm: ArmSettings = field(default_factory=ArmSettings)
    workspace: Workspace | None = None
    """The arm's workspace (``[workspace]``; required with an arm)."""
    control_rate: float = 200.0
    joint_state_rate: float = 500.0
    object_pose_rate: float = 30.0
    sync_to_joint_states: bool = True
    """Start each cycle on a fresh joint state (the module docstring)."""
    thread_priority: int = 0
    """``SCHED_FIFO`` priority (1-99) of the controller's control thread, 0 for the operating
    system's normal scheduling (:mod:`wholehand.robot.realtime`)."""
    qos: dict[str, QoS] = field(default_factory=dict)
    frame_id: str = "world"
    stamp_source: StampSource = "header"
    pose_prediction: float = 0.1
    """The controller carries each object pose forward to the joint state's time at the
    object's velocity between the last two poses, at most this long [s] (0: not at all;
    :class:`~wholehand.loop.filters.PosePredictor`): what makes up for the tracker's
    latency while the object moves (``[object_pose] predict``)."""
    safety: SafetyLimits = field(default_factory=SafetyLimits)
    path: str = ""

    def topic(self, key: str) -> str:
        """The topic of a ``[topics]`` key; "" for an optional one that is off or not given."""
        return self.topics.get(key, "")

    def qos_of(self, topic: str) -> QoS:
        """The QoS of a topic key of ``[topics]`` (reliable, keep last 1 unless set)."""
        return self.qos.get(topic, QoS())

    def link(self) -> str:
        """How the config reaches the robot, for messages: the transport and its settings."""
        if self.transport == "dds":
            peers = f"peers {list(self.dds_peers)}" if self.dds_peers else "multicast discovery"
            where = f", interface {self.dds_interface!r}" if self.dds_interface else ""
            return f"DDS domain {self.domain_id}, {peers}{where}"
        return (
            f"zenoh connect={list(self.connect)} listen={list(self.listen)}, domain "
            f"{self.domain_id}"
        )

    def with_endpoints(
        self, connect: tuple[str, ...] | None = None, listen: tuple[str, ...] | None = None
    ) -> HardwareConfig:
        """A copy with other zenoh endpoints (e.g. from the command line)."""
        return replace(
            self,
            connect=self.connect if connect is None else tuple(connect),
            listen=self.listen if listen is None else tuple(listen),
        )
