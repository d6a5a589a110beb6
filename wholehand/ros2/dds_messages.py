# Cyclone's IDL annotations (sequence[float64], ...) are run-time objects mypy cannot read.
# mypy: disable-error-code="type-arg, assignment, valid-type, arg-type"
"""The ROS 2 messages wholehand speaks as Cyclone DDS IDL structs, for the DDS transport
(:mod:`wholehand.ros2.ros2_dds`).

Each struct has the DDS type name ROS 2 gives the message (``sensor_msgs::msg::dds_::JointState_``)
and the fields of its ``.msg`` file in order, so that its CDR bytes are the message's
(:mod:`wholehand.ros2.messages`; tested byte for byte). No ``from __future__ import
annotations`` here: Cyclone reads the field types from the annotations at run time.
"""

from dataclasses import dataclass, field

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, bounded_str, float64, int32, sequence, uint8, uint32

from wholehand.ros2.messages import (
    BOOL,
    FLOAT64_ARRAY,
    JOINT_STATE,
    JOINT_TRAJECTORY,
    POSE_STAMPED,
    STRING,
    dds_type_name,
)


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Duration(IdlStruct, typename="builtin_interfaces::msg::dds_::Duration_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class JointState(IdlStruct, typename=dds_type_name(JOINT_STATE)):
    header: Header = field(default_factory=Header)
    name: sequence[str] = field(default_factory=list)
    position: sequence[float64] = field(default_factory=list)
    velocity: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseStamped(IdlStruct, typename=dds_type_name(POSE_STAMPED)):
    header: Header = field(default_factory=Header)
    pose: Pose = field(default_factory=Pose)


@dataclass
class MultiArrayDimension(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayDimension_"):
    label: str = ""
    size: uint32 = 0
    stride: uint32 = 0


@dataclass
class MultiArrayLayout(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayLayout_"):
    dim: sequence[MultiArrayDimension] = field(default_factory=list)
    data_offset: uint32 = 0


@dataclass
class Float64MultiArray(IdlStruct, typename=dds_type_name(FLOAT64_ARRAY)):
    layout: MultiArrayLayout = field(default_factory=MultiArrayLayout)
    data: sequence[float64] = field(default_factory=list)


@dataclass
class JointTrajectoryPoint(IdlStruct, typename="trajectory_msgs::msg::dds_::JointTrajectoryPoint_"):
    positions: sequence[float64] = field(default_factory=list)
    velocities: sequence[float64] = field(default_factory=list)
    accelerations: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)
    time_from_start: Duration = field(default_factory=Duration)


@dataclass
class JointTrajectory(IdlStruct, typename=dds_type_name(JOINT_TRAJECTORY)):
    header: Header = field(default_factory=Header)
    joint_names: sequence[str] = field(default_factory=list)
    points: sequence[JointTrajectoryPoint] = field(default_factory=list)


@dataclass
class Bool(IdlStruct, typename=dds_type_name(BOOL)):
    data: bool = False


@dataclass
class String(IdlStruct, typename=dds_type_name(STRING)):
    data: str = ""


IDL_TYPES: dict[str, type[IdlStruct]] = {
    JOINT_STATE: JointState,
    POSE_STAMPED: PoseStamped,
    FLOAT64_ARRAY: Float64MultiArray,
    JOINT_TRAJECTORY: JointTrajectory,
    BOOL: Bool,
    STRING: String,
}
"""The Cyclone IDL struct of each message type wholehand speaks."""


# --- ROS 2's graph: which node owns which endpoints (rmw_dds_common, Jazzy's 16-byte GIDs) ----
@dataclass
class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
    data: array[uint8, 16] = field(default_factory=lambda: [0] * 16)


@dataclass
class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
    node_namespace: bounded_str[256] = "/"
    node_name: bounded_str[256] = ""
    reader_gid_seq: sequence[Gid] = field(default_factory=list)
    writer_gid_seq: sequence[Gid] = field(default_factory=list)


@dataclass
class ParticipantEntitiesInfo(
    IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"
):
    gid: Gid = field(default_factory=Gid)
    node_entities_info_seq: sequence[NodeEntitiesInfo] = field(default_factory=list)


def graph_message(
    participant: bytes, node_name: str, readers: list[bytes], writers: list[bytes]
) -> ParticipantEntitiesInfo:
    """The ``ros_discovery_info`` message of one node in namespace ``/``: the participant's
    GID and the GIDs of the node's readers and writers (16-byte DDS GUIDs)."""
    node = NodeEntitiesInfo(
        node_namespace="/",
        node_name=node_name,
        reader_gid_seq=[Gid(list(g)) for g in readers],
        writer_gid_seq=[Gid(list(g)) for g in writers],
    )
    return ParticipantEntitiesInfo(Gid(list(participant)), [node])
