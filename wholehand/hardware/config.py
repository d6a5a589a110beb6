"""How the controller talks to a robot over ROS 2 messages: a TOML file, parsed and checked.

Schema (times in s, rates in Hz, torques in N*m; every key optional, defaults below)::

    [ros2]
    domain_id = 0                   # ROS_DOMAIN_ID: the first field of every key expression
    distro = "jazzy"                # "humble" publishes without a type hash (rmw_zenoh on Humble)
    mode = "peer"                   # zenoh session mode: "peer" or "client"
    connect = ["tcp/127.0.0.1:7447"]   # endpoints to connect to (rmw_zenohd's default)
    listen = []                     # endpoints to listen on (hw-sim listens, the controller
                                    # connects, so the two need no router)

    [topics]                        # ROS 2 topic names
    joint_states = "/joint_states"                          # sensor_msgs/msg/JointState, in
    object_pose = "/object_pose"                            # geometry_msgs/msg/PoseStamped, in
    torque_command = "/hand_effort_controller/commands"     # std_msgs/msg/Float64MultiArray, out
    arm_command = ""                # Float64MultiArray of arm joint positions, out ("" = none)

    [joints]
    rename = { joint_0 = "allegro_joint_0" }   # model joint -> name in JointState messages
    ignore = ["gripper_joint"]      # names in JointState that are not the hand's (else rejected)
    command = ["joint_0", ...]      # model joints in the order of the torque command's data
                                    # (the effort controller's `joints`); default: the actuated
                                    # hand joints in model order

    [rates]
    control = 200.0                 # control loop [Hz]
    joint_states = 500.0            # what the robot publishes (hw-sim uses it)
    object_pose = 30.0              # what the tracker publishes (hw-sim uses it)
    sync_to_joint_states = true     # start each cycle on a fresh joint state (below)

    [qos]                           # per topic: reliability, history, depth
    torque_command = { reliability = "reliable", history = "keep_last", depth = 1 }

    [object_pose]
    frame_id = "world"              # poses in another frame are rejected
    stamp_source = "header"         # "header": the message's stamp is the image time (the
                                    # paper's handling); "receipt": the time it arrived

    [safety]
    joint_timeout = 0.05            # joint state older than this -> zero torque
    pose_timeout = 0.2              # object pose older than this -> hold, then ramp to zero
    pose_ramp = 0.5                 # time of that ramp to zero
    torque_rate = 20.0              # largest torque change per second [N*m/s]
    watchdog = 0.05                 # no command for this long -> the watchdog ramps down
    max_future_stamp = 0.01         # a stamp further ahead of this clock is rejected

Message ages are measured from the time each message arrived, on this process's monotonic
clock, so a clock offset between robot and controller cannot hide a stream that stopped.

Cycles synchronised to the joint states (``sync_to_joint_states``). A cycle that started on
the newest joint state as it found it would use one up to a joint-state period old (2 ms at
500 Hz), which adds to the delay from measurement to torque. So, when a cycle's time comes and
the newest joint state arrived more than a quarter of a joint-state period ago, the controller
waits for the next one, at most 1.25 joint-state periods and never more than 40 % of the control
period; the schedule of cycles stays that of the control rate.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from wholehand.errors import ConfigError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

Reliability = Literal["reliable", "best_effort"]
History = Literal["keep_last", "keep_all"]
StampSource = Literal["header", "receipt"]

DISTROS = ("humble", "jazzy", "kilted")
"""ROS 2 distributions whose rmw_zenoh key expressions we write."""

TOPICS = ("joint_states", "object_pose", "torque_command", "arm_command")
STAMP_SOURCES: tuple[StampSource, ...] = ("header", "receipt")


@dataclass(frozen=True)
class QoS:
    """The part of a ROS 2 QoS profile rmw_zenoh maps onto zenoh."""

    reliability: Reliability = "reliable"
    history: History = "keep_last"
    depth: int = 1


@dataclass(frozen=True)
class SafetyLimits:
    """The safety rules' times and rates (see :mod:`wholehand.hardware.guard`)."""

    joint_timeout: float = 0.05
    """A joint state older than this [s] -> zero torque."""
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


@dataclass(frozen=True)
class HardwareConfig:
    """Topics, joint names, rates, QoS and safety limits of a ROS 2 robot (the module's
    schema). ``path`` is the file it came from ("" for the defaults)."""

    domain_id: int = 0
    distro: str = "jazzy"
    mode: str = "peer"
    connect: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    listen: tuple[str, ...] = ()
    topics: dict[str, str] = field(
        default_factory=lambda: {
            "joint_states": "/joint_states",
            "object_pose": "/object_pose",
            "torque_command": "/hand_effort_controller/commands",
            "arm_command": "",
        }
    )
    rename: dict[str, str] = field(default_factory=dict)
    ignore: tuple[str, ...] = ()
    command_joints: tuple[str, ...] | None = None
    control_rate: float = 200.0
    joint_state_rate: float = 500.0
    object_pose_rate: float = 30.0
    sync_to_joint_states: bool = True
    """Start each cycle on a fresh joint state (the module docstring)."""
    qos: dict[str, QoS] = field(default_factory=dict)
    frame_id: str = "world"
    stamp_source: StampSource = "header"
    safety: SafetyLimits = field(default_factory=SafetyLimits)
    path: str = ""

    def qos_of(self, topic: str) -> QoS:
        """The QoS of a topic key of ``[topics]`` (reliable, keep last 1 unless set)."""
        return self.qos.get(topic, QoS())

    def with_endpoints(
        self, connect: tuple[str, ...] | None = None, listen: tuple[str, ...] | None = None
    ) -> HardwareConfig:
        """A copy with other zenoh endpoints (e.g. from the command line)."""
        return replace(
            self,
            connect=self.connect if connect is None else tuple(connect),
            listen=self.listen if listen is None else tuple(listen),
        )


def _where(path: str) -> str:
    return path or "hardware config"


def _number(value: Any, what: str, path: str, positive: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"{_where(path)}: {what} must be a finite number, got {value!r}")
    if positive and value <= 0.0:
        raise ConfigError(f"{_where(path)}: {what} must be > 0, got {value!r}")
    return float(value)


def _strings(value: Any, what: str, path: str) -> tuple[str, ...]:
    if not (isinstance(value, list) and all(isinstance(v, str) for v in value)):
        raise ConfigError(f"{_where(path)}: {what} must be a list of strings, got {value!r}")
    return tuple(value)


def _table(raw: dict[str, Any], key: str, known: tuple[str, ...], path: str) -> dict[str, Any]:
    table = raw.get(key, {})
    if not isinstance(table, dict):
        raise ConfigError(f"{_where(path)}: [{key}] must be a table, got {table!r}")
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise ConfigError(
            f"{_where(path)}: unknown keys {unknown} in [{key}]; valid keys: {list(known)}"
        )
    return table


def _qos(value: Any, topic: str, path: str) -> QoS:
    if not isinstance(value, dict) or set(value) - {"reliability", "history", "depth"}:
        raise ConfigError(
            f"{_where(path)}: [qos] {topic} must be a table of reliability, history and depth, "
            f"got {value!r}"
        )
    reliability = value.get("reliability", "reliable")
    history = value.get("history", "keep_last")
    depth = value.get("depth", 1)
    if reliability not in ("reliable", "best_effort"):
        raise ConfigError(
            f"{_where(path)}: [qos] {topic}.reliability must be 'reliable' or 'best_effort', got "
            f"{reliability!r}"
        )
    if history not in ("keep_last", "keep_all"):
        raise ConfigError(
            f"{_where(path)}: [qos] {topic}.history must be 'keep_last' or 'keep_all', got "
            f"{history!r}"
        )
    if isinstance(depth, bool) or not isinstance(depth, int) or depth < 1:
        raise ConfigError(f"{_where(path)}: [qos] {topic}.depth must be an integer >= 1")
    return QoS(reliability, history, depth)


def parse_hardware_config(raw: dict[str, Any], path: str = "") -> HardwareConfig:
    """A :class:`HardwareConfig` from the parsed TOML ``raw`` (the module's schema).

    Raises:
        ConfigError: an unknown table or key, or a value of the wrong kind (named with the file).
    """
    unknown = sorted(
        set(raw) - {"ros2", "topics", "joints", "rates", "qos", "object_pose", "safety"}
    )
    if unknown:
        raise ConfigError(
            f"{_where(path)}: unknown tables {unknown}; valid: ros2, topics, joints, rates, qos, "
            "object_pose, safety"
        )
    ros2 = _table(raw, "ros2", ("domain_id", "distro", "mode", "connect", "listen"), path)
    domain = ros2.get("domain_id", 0)
    if isinstance(domain, bool) or not isinstance(domain, int) or not 0 <= domain <= 232:
        raise ConfigError(f"{_where(path)}: [ros2] domain_id must be an integer 0..232")
    distro = ros2.get("distro", "jazzy")
    if distro not in DISTROS:
        raise ConfigError(f"{_where(path)}: [ros2] distro {distro!r} is not one of {DISTROS}")
    mode = ros2.get("mode", "peer")
    if mode not in ("peer", "client"):
        raise ConfigError(f"{_where(path)}: [ros2] mode must be 'peer' or 'client', got {mode!r}")
    topics = dict(HardwareConfig().topics)
    for key, name in _table(raw, "topics", TOPICS, path).items():
        if not isinstance(name, str) or (name and not name.startswith("/")) or "//" in name:
            raise ConfigError(
                f"{_where(path)}: [topics] {key} must be an absolute ROS 2 topic name such as "
                f"'/joint_states' (or '' for none), got {name!r}"
            )
        topics[key] = name
    for key in ("joint_states", "object_pose", "torque_command"):
        if not topics[key]:
            raise ConfigError(f"{_where(path)}: [topics] {key} must name a topic")
    joints = _table(raw, "joints", ("rename", "ignore", "command"), path)
    rename = joints.get("rename", {})
    if not (isinstance(rename, dict) and all(isinstance(v, str) for v in rename.values())):
        raise ConfigError(f"{_where(path)}: [joints] rename must map joint names to names")
    rates = _table(
        raw, "rates", ("control", "joint_states", "object_pose", "sync_to_joint_states"), path
    )
    sync = rates.get("sync_to_joint_states", True)
    if not isinstance(sync, bool):
        raise ConfigError(
            f"{_where(path)}: [rates] sync_to_joint_states must be true or false, got {sync!r}"
        )
    qos = {
        topic: _qos(value, topic, path) for topic, value in _table(raw, "qos", TOPICS, path).items()
    }
    pose = _table(raw, "object_pose", ("frame_id", "stamp_source"), path)
    stamp_source = pose.get("stamp_source", "header")
    if stamp_source not in STAMP_SOURCES:
        raise ConfigError(
            f"{_where(path)}: [object_pose] stamp_source must be one of {STAMP_SOURCES}, got "
            f"{stamp_source!r}"
        )
    safety_raw = _table(raw, "safety", tuple(SafetyLimits.__dataclass_fields__), path)
    safety = SafetyLimits(**{k: _number(v, f"[safety] {k}", path) for k, v in safety_raw.items()})
    command = joints.get("command")
    return HardwareConfig(
        domain_id=domain,
        distro=distro,
        mode=mode,
        connect=_strings(ros2.get("connect", ["tcp/127.0.0.1:7447"]), "[ros2] connect", path),
        listen=_strings(ros2.get("listen", []), "[ros2] listen", path),
        topics=topics,
        rename=dict(rename),
        ignore=_strings(joints.get("ignore", []), "[joints] ignore", path),
        command_joints=None if command is None else _strings(command, "[joints] command", path),
        control_rate=_number(rates.get("control", 200.0), "[rates] control", path),
        joint_state_rate=_number(rates.get("joint_states", 500.0), "[rates] joint_states", path),
        object_pose_rate=_number(rates.get("object_pose", 30.0), "[rates] object_pose", path),
        sync_to_joint_states=sync,
        qos=qos,
        frame_id=str(pose.get("frame_id", "world")),
        stamp_source=stamp_source,
        safety=safety,
        path=path,
    )


def load_hardware_config(path: str | Path | None = None) -> HardwareConfig:
    """The config of a TOML file (None: the defaults of the module's schema).

    Raises:
        ConfigError: the file is missing, not TOML, or breaks the schema.
    """
    if path is None:
        return HardwareConfig()
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"hardware config {str(p)!r} does not exist; give a TOML file")
    try:
        raw = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{p}: not valid TOML: {err}") from err
    return parse_hardware_config(raw, str(p))
