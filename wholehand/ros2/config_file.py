"""How the controller talks to a robot over ROS 2 messages: a TOML file, parsed and checked.

Schema (times in s, rates in Hz, torques in N*m; every key optional, defaults below)::

    [ros2]
    transport = "zenoh"             # "zenoh": as rmw_zenoh (rmw_zenoh_cpp robots); "dds": as
                                    # rmw_cyclonedds / rmw_fastrtps (a stock ROS 2 install)
    domain_id = 0                   # default: $ROS_DOMAIN_ID, else 0
    distro = "jazzy"                # "humble" publishes without a type hash
    # zenoh only:
    mode = "peer"                   # zenoh session mode: "peer" or "client"
    connect = ["tcp/127.0.0.1:7447"]   # endpoints to connect to (rmw_zenohd's default)
    listen = []                     # endpoints to listen on (hw-sim listens, the controller
                                    # connects, so the two need no router)
    # dds only (both empty: Cyclone DDS's defaults or $CYCLONEDDS_URI, multicast discovery):
    dds_interface = ""              # the network interface's name or address, e.g. "eth0"
    dds_peers = []                  # unicast discovery: the other side's addresses (multicast
                                    # off), e.g. ["192.168.1.10"] or ["127.0.0.1"] on one machine

    [topics]                        # ROS 2 topic names
    joint_states = "/joint_states"                          # sensor_msgs/msg/JointState, in
    object_pose = "/object_pose"                            # geometry_msgs/msg/PoseStamped, in
    torque_command = "/hand_effort_controller/commands"     # std_msgs/msg/Float64MultiArray, out
    arm_command = ""                # the arm's joint position targets, out ("" = no arm)
    hand_position_command = ""      # Float64MultiArray of the hand's position targets while
                                    # reaching, for hand drivers that switch to a position
                                    # interface on it; torques go on torque_command while
                                    # regulating ("" = torques throughout: a PD law in torque)
    stop = "/wholehand/stop"        # std_msgs/msg/Bool, in: true stops the robot ("" = none)
    status = "/wholehand/status"    # std_msgs/msg/String, out: the controller's stage on each
                                    # change and every second, e.g. "regulate" ("" = none)

    [joints]
    rename = { joint_0 = "allegro_joint_0" }   # model joint -> name in JointState messages
    ignore = ["gripper_joint"]      # names in JointState that are not the hand's (else rejected)
    command = ["joint_0", ...]      # REQUIRED: the torque command's joints in its order (the
                                    # hand controller's `joints` parameter), model names or
                                    # their names after `rename`; every actuated hand joint once

    [arm]                           # with [topics] arm_command only
    joints = ["joint1", ...]        # REQUIRED: the arm controller's `joints`, in its order
    interface = "position"          # "position": Float64MultiArray for ForwardCommandController
                                    # (interface_name: position); "trajectory": a
                                    # trajectory_msgs/msg/JointTrajectory stream for
                                    # joint_trajectory_controller
    velocity_scale = 0.5            # targets move at most this fraction of the URDF's joint
                                    # velocity limits
    home = [0.0, ...]               # home posture [rad] (default: the assembly's [assembly] home)

    [workspace]                     # REQUIRED with an arm (world frame [m])
    palm_min = [0.2, -0.4, 0.05]    # the palm's targets are kept in this box
    palm_max = [0.8, 0.4, 0.6]
    object_min = [0.25, -0.35, 0.0] # an object outside this box sends the arm home
    object_max = [0.75, 0.35, 0.5]
    table = { top = 0.0, centre = [0.45, 0.0], size = [1.5, 1.5] }   # optional: a table the
                                    # reacher keeps the hand above

    [rates]
    control = 200.0                 # control loop [Hz]
    joint_states = 500.0            # what the robot publishes (hw-sim uses it)
    object_pose = 30.0              # what the tracker publishes (hw-sim uses it)
    sync_to_joint_states = true     # start each cycle on a fresh joint state (below)
    thread_priority = 0             # SCHED_FIFO priority (1-99) of the control thread, as
                                    # ros2_control's; needs CAP_SYS_NICE or `ulimit -r`; 0: off

    [qos]                           # per topic: reliability, history, depth
    torque_command = { reliability = "reliable", history = "keep_last", depth = 1 }

    [object_pose]
    frame_id = "world"              # poses in another frame are rejected
    stamp_source = "header"         # "header": the message's stamp is the image time (the
                                    # paper's handling); "receipt": the time it arrived
    predict = 0.1                   # carry each pose forward to the joint state's time at the
                                    # object's velocity, at most this long [s] (0: off)

    [safety]
    joint_timeout = 0.05            # joint state older than this -> hold the last torque
    joint_hold = 0.1                # ... for this long, then ramp it to zero
    joint_ramp = 0.25               # over this time; past it (or no joint state) zero torque
    pose_timeout = 0.2              # object pose older than this -> hold, then ramp to zero
    pose_ramp = 0.5                 # time of that ramp to zero
    torque_rate = 20.0              # largest torque change per second [N*m/s]
    watchdog = 0.05                 # no command for this long -> the watchdog ramps down
    max_future_stamp = 0.01         # a stamp further ahead of this clock is rejected
    exit_ramp = 0.5                 # on every exit the hand torques ramp to zero over this time

Message ages are measured from the time each message arrived, on this process's monotonic
clock, so a clock offset between robot and controller cannot hide a stream that stopped.

Cycles synchronised to the joint states (``sync_to_joint_states``). A cycle that started on
the newest joint state as it found it would use one up to a joint-state period old (2 ms at
500 Hz), which adds to the delay from measurement to torque. So, when a cycle's time comes and
the newest joint state arrived more than a quarter of a joint-state period ago, the controller
waits for the next one, at most 1.25 joint-state periods, never more than 40 % of the control
period, and never so long that the recent cycles' computation would no longer fit in the period
(:mod:`wholehand.ros2.joint_sync`); the schedule of cycles stays that of the control rate.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path
from typing import Any

from wholehand.backends.table import Table
from wholehand.errors import ConfigError
from wholehand.reaching.workspace import Box, Workspace
from wholehand.ros2.config import (
    DISTROS,
    STAMP_SOURCES,
    TOPICS,
    TRANSPORTS,
    ArmSettings,
    HardwareConfig,
    QoS,
    SafetyLimits,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def _environment_domain() -> int:
    """``$ROS_DOMAIN_ID`` as ROS 2 reads it (0 when unset or empty)."""
    value = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not value:
        return 0
    if not value.isdigit() or int(value) > 232:
        raise ConfigError(
            f"ROS_DOMAIN_ID={value!r} is not a domain id 0..232; unset it or set it as the "
            "robot's stack does"
        )
    return int(value)


def _where(path: str) -> str:
    return path or "hardware config"


def _number(value: Any, what: str, path: str, positive: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"{_where(path)}: {what} must be a finite number, got {value!r}")
    if positive and value <= 0.0:
        raise ConfigError(f"{_where(path)}: {what} must be > 0, got {value!r}")
    return float(value)


def _prediction(value: Any, path: str) -> float:
    horizon = _number(value, "[object_pose] predict", path, positive=False)
    if horizon < 0.0:
        raise ConfigError(
            f"{_where(path)}: [object_pose] predict must be >= 0 [s] (0: no prediction), got "
            f"{value!r}"
        )
    return horizon


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


TABLES = ("ros2", "topics", "joints", "rates", "qos", "object_pose", "safety", "arm", "workspace")


def _joint_list(value: Any, what: str, path: str) -> tuple[str, ...]:
    """A non-empty list of joint names without repeats."""
    names = _strings(value, what, path)
    if not names:
        raise ConfigError(f"{_where(path)}: {what} is empty; list the controller's joints")
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise ConfigError(f"{_where(path)}: {what} lists {repeated} more than once")
    return names


def _arm(raw: dict[str, Any], has_arm: bool, path: str) -> ArmSettings:
    table = _table(raw, "arm", ("joints", "interface", "velocity_scale", "home"), path)
    if not has_arm:
        if table:
            raise ConfigError(
                f"{_where(path)}: [arm] is set but [topics] arm_command is not; name the arm "
                "controller's command topic or remove [arm]"
            )
        return ArmSettings()
    if "joints" not in table:
        raise ConfigError(
            f"{_where(path)}: [arm] joints is missing: list the arm controller's joints in the "
            'order of its `joints` parameter, e.g. joints = ["joint1", "joint2", ...]'
        )
    interface = table.get("interface", "position")
    if interface not in ("position", "trajectory"):
        raise ConfigError(
            f"{_where(path)}: [arm] interface must be 'position' or 'trajectory', got {interface!r}"
        )
    scale = _number(table.get("velocity_scale", 0.5), "[arm] velocity_scale", path)
    if scale > 1.0:
        raise ConfigError(f"{_where(path)}: [arm] velocity_scale must be in (0, 1], got {scale}")
    joints = _joint_list(table["joints"], "[arm] joints", path)
    home = table.get("home")
    if home is not None:
        home = tuple(_number(v, "[arm] home", path, positive=False) for v in _list(home, path))
        if len(home) != len(joints):
            raise ConfigError(
                f"{_where(path)}: [arm] home has {len(home)} values for {len(joints)} joints"
            )
    return ArmSettings(joints, interface, scale, home)


def _list(value: Any, path: str) -> list[Any]:
    if not isinstance(value, list):
        raise ConfigError(f"{_where(path)}: expected a list of numbers, got {value!r}")
    return value


def _box(table: dict[str, Any], key: str, path: str) -> Box:
    lower, upper = table.get(f"{key}_min"), table.get(f"{key}_max")
    if lower is None or upper is None:
        raise ConfigError(
            f"{_where(path)}: [workspace] needs {key}_min and {key}_max (x, y, z in the world "
            "frame [m])"
        )
    lo = tuple(_number(v, f"[workspace] {key}_min", path, False) for v in _list(lower, path))
    hi = tuple(_number(v, f"[workspace] {key}_max", path, False) for v in _list(upper, path))
    return Box(lo, hi, f"{_where(path)}: [workspace] {key}")  # type: ignore[arg-type]


def _workspace(raw: dict[str, Any], has_arm: bool, path: str) -> Workspace | None:
    known = ("palm_min", "palm_max", "object_min", "object_max", "table")
    table = _table(raw, "workspace", known, path)
    if not table:
        if has_arm:
            raise ConfigError(
                f"{_where(path)}: [workspace] is missing: an arm needs palm_min, palm_max, "
                "object_min and object_max (world frame [m]); see docs/hardware.md"
            )
        return None
    top = table.get("table")
    surface = None
    if top is not None:
        if not isinstance(top, dict) or set(top) - {"top", "centre", "size"}:
            raise ConfigError(
                f"{_where(path)}: [workspace] table takes top [m], centre [x, y] and size "
                f"[x, y], got {top!r}"
            )
        surface = Table(
            top=_number(top.get("top", 0.0), "[workspace] table.top", path, positive=False),
            centre=tuple(_list(top.get("centre", [0.0, 0.0]), path)),
            size=tuple(_list(top.get("size", [0.8, 0.8]), path)),
        )
    return Workspace(_box(table, "palm", path), _box(table, "object", path), surface)


def _ros2(raw: dict[str, Any], path: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """The [ros2] table and its checked settings: transport, domain_id, distro, mode and
    dds_interface (the :class:`HardwareConfig` fields of those names)."""
    ros2 = _table(
        raw,
        "ros2",
        ("transport", "domain_id", "distro", "mode", "connect", "listen")
        + ("dds_interface", "dds_peers"),
        path,
    )
    transport = ros2.get("transport", "zenoh")
    if transport not in TRANSPORTS:
        raise ConfigError(
            f"{_where(path)}: [ros2] transport must be one of {TRANSPORTS}, got {transport!r}"
        )
    interface = ros2.get("dds_interface", "")
    if not isinstance(interface, str):
        raise ConfigError(
            f"{_where(path)}: [ros2] dds_interface must be a string such as 'eth0', got "
            f"{interface!r}"
        )
    domain = ros2.get("domain_id", _environment_domain())
    if isinstance(domain, bool) or not isinstance(domain, int) or not 0 <= domain <= 232:
        raise ConfigError(f"{_where(path)}: [ros2] domain_id must be an integer 0..232")
    distro = ros2.get("distro", "jazzy")
    if distro not in DISTROS:
        raise ConfigError(f"{_where(path)}: [ros2] distro {distro!r} is not one of {DISTROS}")
    mode = ros2.get("mode", "peer")
    if mode not in ("peer", "client"):
        raise ConfigError(f"{_where(path)}: [ros2] mode must be 'peer' or 'client', got {mode!r}")
    settings = {
        "transport": transport,
        "domain_id": domain,
        "distro": distro,
        "mode": mode,
        "dds_interface": interface,
    }
    return ros2, settings


def _topics(raw: dict[str, Any], path: str) -> dict[str, str]:
    """Every topic's name: the defaults with [topics] applied; the three the controller
    cannot run without must be named."""
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
    return topics


def parse_hardware_config(raw: dict[str, Any], path: str = "") -> HardwareConfig:
    """A :class:`HardwareConfig` from the parsed TOML ``raw`` (the module's schema).

    Raises:
        ConfigError: an unknown table or key, or a value of the wrong kind (named with the file).
    """
    unknown = sorted(set(raw) - set(TABLES))
    if unknown:
        raise ConfigError(f"{_where(path)}: unknown tables {unknown}; valid: {', '.join(TABLES)}")
    ros2, settings = _ros2(raw, path)
    topics = _topics(raw, path)
    joints = _table(raw, "joints", ("rename", "ignore", "command"), path)
    rename = joints.get("rename", {})
    if not (isinstance(rename, dict) and all(isinstance(v, str) for v in rename.values())):
        raise ConfigError(f"{_where(path)}: [joints] rename must map joint names to names")
    rates = _table(
        raw,
        "rates",
        ("control", "joint_states", "object_pose", "sync_to_joint_states", "thread_priority"),
        path,
    )
    sync = rates.get("sync_to_joint_states", True)
    if not isinstance(sync, bool):
        raise ConfigError(
            f"{_where(path)}: [rates] sync_to_joint_states must be true or false, got {sync!r}"
        )
    priority = rates.get("thread_priority", 0)
    if isinstance(priority, bool) or not isinstance(priority, int) or not 0 <= priority <= 99:
        raise ConfigError(
            f"{_where(path)}: [rates] thread_priority must be a whole number, 0 (the normal "
            f"scheduling) or a SCHED_FIFO priority 1-99 (ros2_control uses 50), got {priority!r}"
        )
    qos = {
        topic: _qos(value, topic, path) for topic, value in _table(raw, "qos", TOPICS, path).items()
    }
    pose = _table(raw, "object_pose", ("frame_id", "stamp_source", "predict"), path)
    stamp_source = pose.get("stamp_source", "header")
    if stamp_source not in STAMP_SOURCES:
        raise ConfigError(
            f"{_where(path)}: [object_pose] stamp_source must be one of {STAMP_SOURCES}, got "
            f"{stamp_source!r}"
        )
    safety_raw = _table(raw, "safety", tuple(SafetyLimits.__dataclass_fields__), path)
    safety = SafetyLimits(**{k: _number(v, f"[safety] {k}", path) for k, v in safety_raw.items()})
    if "command" not in joints:
        raise ConfigError(
            f"{_where(path)}: [joints] command is missing: list the torque command's joints in "
            "the order of the hand controller's `joints` parameter, e.g. command = "
            '["joint_0", "joint_1", ...] (model names or their names after [joints] rename)'
        )
    command = _joint_list(joints["command"], "[joints] command", path)
    arm = _arm(raw, bool(topics["arm_command"]), path)
    return HardwareConfig(
        **settings,
        connect=_strings(ros2.get("connect", ["tcp/127.0.0.1:7447"]), "[ros2] connect", path),
        listen=_strings(ros2.get("listen", []), "[ros2] listen", path),
        dds_peers=_strings(ros2.get("dds_peers", []), "[ros2] dds_peers", path),
        topics=topics,
        rename=dict(rename),
        ignore=_strings(joints.get("ignore", []), "[joints] ignore", path),
        command_joints=command,
        arm=arm,
        workspace=_workspace(raw, bool(topics["arm_command"]), path),
        control_rate=_number(rates.get("control", 200.0), "[rates] control", path),
        joint_state_rate=_number(rates.get("joint_states", 500.0), "[rates] joint_states", path),
        object_pose_rate=_number(rates.get("object_pose", 30.0), "[rates] object_pose", path),
        sync_to_joint_states=sync,
        thread_priority=priority,
        qos=qos,
        frame_id=str(pose.get("frame_id", "world")),
        stamp_source=stamp_source,
        pose_prediction=_prediction(pose.get("predict", 0.1), path),
        safety=safety,
        path=path,
    )


HAND_CONFIG_FILE = "ros2.toml"
"""A hand folder's hardware config, read when no other is given."""


def hand_hardware_config(hand: str | Path) -> Path:
    """The hardware config in a hand's folder (``ros2.toml`` beside its hand.toml).

    Raises:
        ConfigError: the hand is unknown, or its folder has no hardware config.
    """
    from wholehand.models.hand_folders import resolve_hand_config

    path = resolve_hand_config(hand).parent / HAND_CONFIG_FILE
    if not path.is_file():
        raise ConfigError(
            f"no hardware config for hand {str(hand)!r}: give --config FILE, or write "
            f"{path} (copy robots/allegro_right/{HAND_CONFIG_FILE}; docs/hardware.md)"
        )
    return path


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
