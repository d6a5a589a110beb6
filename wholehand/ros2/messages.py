"""The ROS 2 messages the hardware path speaks, CDR-encoded by ``rosbags``' typestore.

- ``sensor_msgs/msg/JointState`` (in): joint names, positions [rad], velocities [rad/s],
  efforts [N*m], with a header stamp (the measurement time).
- ``geometry_msgs/msg/PoseStamped`` (in): the tracked object pose in ``header.frame_id``,
  stamped with the image time (or the processing time, see ``stamp_source``).
- ``std_msgs/msg/Float64MultiArray`` (out): torque commands [N*m] in the order of the effort
  controller's joints, and arm position targets [rad] (``ForwardCommandController``).
- ``trajectory_msgs/msg/JointTrajectory`` (out): arm position targets as one point for
  ``joint_trajectory_controller``.
- ``std_msgs/msg/Bool`` (in): the stop topic (true: stop).
- ``std_msgs/msg/String`` (out): the status topic (the controller's stage).

Payloads are CDR with the 4-byte encapsulation header (little endian ``00 01 00 00``), exactly as
a ROS 2 node serialises them. Decoding a payload that is not such a message raises
:class:`MessageError`; the hardware backend counts it and keeps the last good sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
import numpy.typing as npt
from rosbags.typesys import Stores, get_typestore

from wholehand.errors import WholehandError

FloatArray = npt.NDArray[np.float64]

JOINT_STATE = "sensor_msgs/msg/JointState"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
FLOAT64_ARRAY = "std_msgs/msg/Float64MultiArray"
JOINT_TRAJECTORY = "trajectory_msgs/msg/JointTrajectory"
BOOL = "std_msgs/msg/Bool"
STRING = "std_msgs/msg/String"


class MessageError(WholehandError):
    """A payload that is not the expected message (truncated, another type, garbage)."""


RECORDING_STORES = {"humble": Stores.ROS2_HUMBLE}
"""A distro whose message definitions differ from Jazzy's in what a recording writes: Humble's
``visualization_msgs/msg/Marker`` lacks the ``ARROW_STRIP`` constant (its fields, textures
included, are Jazzy's: the bytes are the same)."""


@cache
def typestore(distro: str = "jazzy") -> Any:
    """The ROS 2 typestore of ``distro`` (Jazzy's unless :data:`RECORDING_STORES` names
    another; the messages on the wire are the same in every ROS 2 distro), with the
    (de)serialisers of wholehand's messages generated: rosbags writes a type's code on its
    first use (about 5 ms), which must not fall in a control cycle."""
    store = get_typestore(RECORDING_STORES.get(distro, Stores.ROS2_JAZZY))
    for msgtype in (JOINT_STATE, POSE_STAMPED, FLOAT64_ARRAY, JOINT_TRAJECTORY, BOOL, STRING):
        store.get_msgdef(msgtype)
    return store


def type_hash(msgtype: str) -> str:
    """The RIHS01 type hash of a message type (``RIHS01_<64 hex>``), as rmw_zenoh keys it."""
    return str(typestore().hash_rihs01(msgtype))


def dds_type_name(msgtype: str) -> str:
    """``sensor_msgs/msg/JointState`` -> ``sensor_msgs::msg::dds_::JointState_``."""
    pkg, kind, name = msgtype.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def stamp_seconds(stamp: Any) -> float:
    """A ``builtin_interfaces/msg/Time`` as seconds."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def _time(seconds: float) -> Any:
    ts = typestore()
    sec = math.floor(seconds)
    nanosec = min(int(round((seconds - sec) * 1e9)), 999_999_999)
    return ts.types["builtin_interfaces/msg/Time"](sec=int(sec), nanosec=nanosec)


def _header(stamp: float, frame_id: str) -> Any:
    return typestore().types["std_msgs/msg/Header"](stamp=_time(stamp), frame_id=frame_id)


def _decode(payload: bytes, msgtype: str) -> Any:
    try:
        return typestore().deserialize_cdr(payload, msgtype)
    except Exception as err:  # noqa: BLE001 - any decoder failure is a malformed message
        raise MessageError(
            f"payload of {len(payload)} bytes is not a CDR {msgtype}: {type(err).__name__}: {err}"
        ) from err


# --- JointState --------------------------------------------------------------------------------
@dataclass(frozen=True)
class JointStateMsg:
    """A decoded ``sensor_msgs/msg/JointState``."""

    stamp: float
    """Header stamp [s]."""
    names: tuple[str, ...]
    position: FloatArray
    """(len(names),) [rad or m]."""
    velocity: FloatArray
    """(len(names),) or (0,) when not sent [rad/s]."""
    effort: FloatArray
    """(len(names),) or (0,) when not sent [N*m]."""


def encode_joint_state(
    stamp: float,
    names: list[str],
    position: npt.ArrayLike,
    velocity: npt.ArrayLike = (),
    effort: npt.ArrayLike = (),
) -> bytes:
    """CDR bytes of a JointState stamped ``stamp`` [s]."""
    msg = typestore().types[JOINT_STATE](
        header=_header(stamp, ""),
        name=list(names),
        position=np.asarray(position, dtype=np.float64),
        velocity=np.asarray(velocity, dtype=np.float64),
        effort=np.asarray(effort, dtype=np.float64),
    )
    return bytes(typestore().serialize_cdr(msg, JOINT_STATE))


def decode_joint_state(payload: bytes) -> JointStateMsg:
    """The JointState in ``payload``.

    Raises:
        MessageError: not a CDR JointState.
    """
    msg = _decode(payload, JOINT_STATE)
    return JointStateMsg(
        stamp_seconds(msg.header.stamp),
        tuple(msg.name),
        np.asarray(msg.position, dtype=np.float64),
        np.asarray(msg.velocity, dtype=np.float64),
        np.asarray(msg.effort, dtype=np.float64),
    )


# --- PoseStamped -------------------------------------------------------------------------------
@dataclass(frozen=True)
class PoseMsg:
    """A decoded ``geometry_msgs/msg/PoseStamped``."""

    stamp: float
    """Header stamp [s]."""
    frame_id: str
    position: FloatArray
    """(3,) [m] in ``frame_id``."""
    quat_xyzw: FloatArray
    """(4,) orientation quaternion, ROS order (x, y, z, w); not necessarily unit."""


def encode_pose(stamp: float, frame_id: str, wMo: FloatArray) -> bytes:
    """CDR bytes of a PoseStamped of the (4, 4) pose ``wMo`` in ``frame_id``."""
    import pinocchio as pin

    ts = typestore()
    x, y, z, w = pin.Quaternion(np.asarray(wMo[:3, :3], dtype=float)).coeffs()
    geometry = "geometry_msgs/msg/"
    pose = ts.types[geometry + "Pose"](
        position=ts.types[geometry + "Point"](
            x=float(wMo[0, 3]), y=float(wMo[1, 3]), z=float(wMo[2, 3])
        ),
        orientation=ts.types[geometry + "Quaternion"](
            x=float(x), y=float(y), z=float(z), w=float(w)
        ),
    )
    msg = ts.types[POSE_STAMPED](header=_header(stamp, frame_id), pose=pose)
    return bytes(ts.serialize_cdr(msg, POSE_STAMPED))


def decode_pose(payload: bytes) -> PoseMsg:
    """The PoseStamped in ``payload``.

    Raises:
        MessageError: not a CDR PoseStamped.
    """
    msg = _decode(payload, POSE_STAMPED)
    p, o = msg.pose.position, msg.pose.orientation
    return PoseMsg(
        stamp_seconds(msg.header.stamp),
        str(msg.header.frame_id),
        np.array([p.x, p.y, p.z], dtype=np.float64),
        np.array([o.x, o.y, o.z, o.w], dtype=np.float64),
    )


# --- Float64MultiArray -------------------------------------------------------------------------
def encode_array(values: npt.ArrayLike) -> bytes:
    """CDR bytes of a Float64MultiArray with an empty layout (what
    ``JointGroupEffortController`` and ``JointGroupPositionController`` read)."""
    ts = typestore()
    layout = ts.types["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)
    msg = ts.types[FLOAT64_ARRAY](layout=layout, data=np.asarray(values, dtype=np.float64))
    return bytes(ts.serialize_cdr(msg, FLOAT64_ARRAY))


def decode_array(payload: bytes) -> FloatArray:
    """The data of the Float64MultiArray in ``payload``.

    Raises:
        MessageError: not a CDR Float64MultiArray.
    """
    return np.asarray(_decode(payload, FLOAT64_ARRAY).data, dtype=np.float64)


# --- JointTrajectory ---------------------------------------------------------------------------
def encode_joint_trajectory(
    names: list[str], position: npt.ArrayLike, time_from_start: float
) -> bytes:
    """CDR bytes of a JointTrajectory of one point: reach ``position`` [rad] of the joints
    ``names`` ``time_from_start`` [s] after the message arrives (header stamp zero: start now,
    as joint_trajectory_controller reads it)."""
    ts = typestore()
    sec = math.floor(time_from_start)
    duration = ts.types["builtin_interfaces/msg/Duration"](
        sec=int(sec), nanosec=int(round((time_from_start - sec) * 1e9))
    )
    empty = np.zeros(0, dtype=np.float64)
    point = ts.types["trajectory_msgs/msg/JointTrajectoryPoint"](
        positions=np.asarray(position, dtype=np.float64),
        velocities=empty,
        accelerations=empty,
        effort=empty,
        time_from_start=duration,
    )
    msg = ts.types[JOINT_TRAJECTORY](
        header=_header(0.0, ""), joint_names=list(names), points=[point]
    )
    return bytes(ts.serialize_cdr(msg, JOINT_TRAJECTORY))


def decode_joint_trajectory(payload: bytes) -> tuple[tuple[str, ...], FloatArray]:
    """The joint names and the last point's positions of the JointTrajectory in ``payload``.

    Raises:
        MessageError: not a CDR JointTrajectory, or one without points.
    """
    msg = _decode(payload, JOINT_TRAJECTORY)
    if not msg.points:
        raise MessageError("JointTrajectory without points")
    return tuple(msg.joint_names), np.asarray(msg.points[-1].positions, dtype=np.float64)


# --- Bool ---------------------------------------------------------------------------------------
def encode_bool(value: bool) -> bytes:
    """CDR bytes of a std_msgs/msg/Bool."""
    ts = typestore()
    return bytes(ts.serialize_cdr(ts.types[BOOL](data=bool(value)), BOOL))


def decode_bool(payload: bytes) -> bool:
    """The data of the std_msgs/msg/Bool in ``payload``.

    Raises:
        MessageError: not a CDR Bool.
    """
    return bool(_decode(payload, BOOL).data)


# --- String -------------------------------------------------------------------------------------
def encode_string(value: str) -> bytes:
    """CDR bytes of a std_msgs/msg/String."""
    ts = typestore()
    return bytes(ts.serialize_cdr(ts.types[STRING](data=str(value)), STRING))


def decode_string(payload: bytes) -> str:
    """The data of the std_msgs/msg/String in ``payload``.

    Raises:
        MessageError: not a CDR String.
    """
    return str(_decode(payload, STRING).data)
