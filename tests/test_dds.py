"""The DDS transport against ROS 2's conventions: Cyclone DDS's own serialiser writes the same
bytes as rosbags' for every message, and a second participant sees the names, type names and
USER_DATA that rmw_cyclonedds writes (the DDS discovery data, read back through Cyclone)."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest
from cyclonedds.builtin import (
    BuiltinDataReader,
    BuiltinTopicDcpsParticipant,
    BuiltinTopicDcpsPublication,
)
from cyclonedds.core import (
    InstanceState,
    Policy,
    Qos,
    ReadCondition,
    SampleState,
    ViewState,
    WaitSet,
)
from cyclonedds.domain import DomainParticipant
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from wholehand.errors import ConfigError
from wholehand.ros2 import messages as msgs
from wholehand.ros2.config import HardwareConfig, QoS
from wholehand.ros2.config_file import load_hardware_config
from wholehand.ros2.dds_messages import IDL_TYPES, ParticipantEntitiesInfo
from wholehand.ros2.messages import MessageError
from wholehand.ros2.ros2_dds import DdsTransport, dds_topic_name, domain_xml, endpoint_qos

DOMAIN = 100 + (os.getpid() + 50) % 100
"""A domain of this test process alone (apart from test_hardware's)."""
LOOPBACK = {"dds_interface": "127.0.0.1", "dds_peers": ("127.0.0.1",)}


def _config(**changes) -> HardwareConfig:
    return HardwareConfig(transport="dds", domain_id=DOMAIN, **(LOOPBACK | changes))


PAYLOADS = {
    msgs.JOINT_STATE: msgs.encode_joint_state(
        1234.5, ["j0", "joint_1"], np.array([0.1, -0.2]), np.array([1.0, 2.0]), np.zeros(2)
    ),
    msgs.POSE_STAMPED: msgs.encode_pose(
        7.25, "world", np.array([[0, -1, 0, 0.1], [1, 0, 0, 0.2], [0, 0, 1, 0.3], [0, 0, 0, 1.0]])
    ),
    msgs.FLOAT64_ARRAY: msgs.encode_array([0.5, -0.25, 0.125]),
    msgs.JOINT_TRAJECTORY: msgs.encode_joint_trajectory(("a", "b"), np.array([0.3, 0.4]), 0.05),
    msgs.BOOL: msgs.encode_bool(True),
    msgs.STRING: msgs.encode_string("regulate"),
}


@pytest.mark.parametrize("msgtype", sorted(PAYLOADS))
def test_cyclone_writes_every_message_as_rosbags_does(msgtype):
    payload = PAYLOADS[msgtype]
    sample = IDL_TYPES[msgtype].deserialize(payload)
    assert sample.serialize() == payload
    assert type(sample).__idl_typename__ == msgs.dds_type_name(msgtype)


def test_cyclone_reads_the_fields_rosbags_wrote():
    js = IDL_TYPES[msgs.JOINT_STATE].deserialize(PAYLOADS[msgs.JOINT_STATE])
    assert (js.header.stamp.sec, js.header.stamp.nanosec) == (1234, 500_000_000)
    assert js.name == ["j0", "joint_1"] and js.position == [0.1, -0.2]
    pose = IDL_TYPES[msgs.POSE_STAMPED].deserialize(PAYLOADS[msgs.POSE_STAMPED])
    q = pose.pose.orientation  # 90 deg about z
    np.testing.assert_allclose([q.x, q.y, q.z, q.w], [0, 0, np.sqrt(0.5), np.sqrt(0.5)])
    assert pose.header.frame_id == "world" and pose.pose.position.z == 0.3


def test_topic_names_are_ros2s():
    assert dds_topic_name("/hand/commands") == "rt/hand/commands"
    with pytest.raises(ConfigError, match="absolute"):
        dds_topic_name("joint_states")


def test_qos_is_mapped_as_rmw_cyclonedds_maps_it():
    reliable = endpoint_qos(QoS("reliable", "keep_last", 3), msgs.JOINT_STATE, "jazzy")
    assert reliable[Policy.History] == Policy.History.KeepLast(3)
    assert isinstance(reliable[Policy.Reliability], Policy.Reliability.Reliable)
    assert reliable[Policy.Durability] == Policy.Durability.Volatile
    digest = msgs.type_hash(msgs.JOINT_STATE)
    assert reliable[Policy.Userdata].data == f"typehash={digest};".encode()
    best = endpoint_qos(QoS("best_effort", "keep_all", 1), msgs.BOOL, "humble")
    assert best[Policy.Reliability] == Policy.Reliability.BestEffort
    assert best[Policy.History] == Policy.History.KeepAll
    assert Policy.Userdata not in best  # Humble publishes no type hash


def test_domain_settings_become_cyclones_configuration():
    assert domain_xml(HardwareConfig(transport="dds")) is None
    xml = domain_xml(HardwareConfig(transport="dds", domain_id=3, dds_interface="eth0"))
    assert '<Domain Id="3">' in xml and '<NetworkInterface name="eth0"/>' in xml
    assert "AllowMulticast" not in xml
    xml = domain_xml(_config())
    assert '<NetworkInterface address="127.0.0.1"/>' in xml
    assert "<AllowMulticast>false</AllowMulticast>" in xml and '<Peer address="127.0.0.1"/>' in xml


def test_a_second_setting_of_an_open_domain_is_refused():
    node = DdsTransport(_config(), "first")
    try:
        with pytest.raises(ConfigError, match="already open"):
            DdsTransport(_config(dds_peers=("10.0.0.2",)), "second")
    finally:
        node.close()


ATTEMPTS = 200
"""Publications tried until discovery has matched the endpoints (each waits up to 50 ms)."""


def _published_until_received(publish, received: threading.Event) -> None:
    """Publish until the subscriber's callback sets ``received``: samples sent before the
    endpoints have discovered each other are lost (volatile durability)."""
    for _ in range(ATTEMPTS):
        publish()
        if received.wait(0.05):
            return
    pytest.fail(f"nothing received after {ATTEMPTS} publications")


def _wait_for(reader, accept) -> None:
    """Hand ``reader``'s samples to ``accept`` until it returns True, waking on each arrival
    (a WaitSet on the reader, not a clock)."""
    waitset = WaitSet(reader.participant)
    waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    for _ in range(ATTEMPTS):
        if accept(reader.take(N=32)):
            return
        waitset.wait(duration(milliseconds=50))
    pytest.fail("the expected discovery data never arrived")


def test_a_sample_crosses_with_its_bytes_and_source_timestamp():
    config = _config()
    robot, controller = DdsTransport(config, "robot"), DdsTransport(config, "controller")
    got: list = []
    arrived = threading.Event()

    def on_joints(payload, meta, t) -> None:
        got.append((payload, meta))
        arrived.set()

    try:
        controller.subscriber("joint_states", msgs.JOINT_STATE, on_joints)
        pub = robot.publisher("joint_states", msgs.JOINT_STATE)
        payload = PAYLOADS[msgs.JOINT_STATE]
        _published_until_received(lambda: pub.put(payload, 1_700_000_000_123_456_789), arrived)
        received, meta = got[0]
        assert received == payload
        assert meta.source_timestamp == 1_700_000_000_123_456_789 and len(meta.source) == 16
        stops: list[bool] = []  # 5 bytes: padded to 8 on the wire, read back as it was
        stopped = threading.Event()

        def on_stop(payload, meta, t) -> None:
            stops.append(msgs.decode_bool(payload))
            stopped.set()

        controller.subscriber("stop", msgs.BOOL, on_stop)
        stop = robot.publisher("stop", msgs.BOOL)
        _published_until_received(lambda: stop.put(msgs.encode_bool(True)), stopped)
        assert stops[0] is True
        with pytest.raises(MessageError, match="not a little-endian CDR sensor_msgs/msg/Joint"):
            pub.put(b"\x01\x00\x00\x00 big-endian")
    finally:
        robot.close()
        controller.close()


def test_discovery_carries_ros2s_names_types_and_user_data():
    node = DdsTransport(_config(), "wholehand_controller")
    node.publisher("torque_command", msgs.FLOAT64_ARRAY)
    node.subscriber("joint_states", msgs.JOINT_STATE, lambda *_: None)
    watcher = DomainParticipant(DOMAIN)
    try:
        publications = BuiltinDataReader(watcher, BuiltinTopicDcpsPublication)
        participants = BuiltinDataReader(watcher, BuiltinTopicDcpsParticipant)
        found: dict[str, object] = {}

        def commands_seen(samples) -> bool:
            found.update({s.topic_name: s for s in samples if s.topic_name.startswith("rt/")})
            return "rt/hand_effort_controller/commands" in found

        _wait_for(publications, commands_seen)
        pub = found["rt/hand_effort_controller/commands"]
        assert pub.type_name == "std_msgs::msg::dds_::Float64MultiArray_"
        digest = msgs.type_hash(msgs.FLOAT64_ARRAY)
        assert pub.qos[Policy.Userdata].data == f"typehash={digest};".encode()
        assert any(
            Policy.Userdata in p.qos and p.qos[Policy.Userdata].data == b"enclave=/;"
            for p in participants.read(N=32)
        )
        # ROS 2's graph (what `ros2 node list` reads): the node, its participant and endpoints.
        graph_qos = Qos(
            Policy.Reliability.Reliable(duration(seconds=1)),
            Policy.Durability.TransientLocal,
            Policy.History.KeepLast(1),
        )
        graph = DataReader(
            watcher, Topic(watcher, "ros_discovery_info", ParticipantEntitiesInfo), qos=graph_qos
        )
        infos: list = []
        _wait_for(graph, lambda samples: bool(infos.extend(samples) or infos))
        info = infos[-1]
        (entities,) = info.node_entities_info_seq
        assert (entities.node_namespace, entities.node_name) == ("/", "wholehand_controller")
        assert bytes(info.gid.data) == node.participant.guid.bytes
        assert [bytes(g.data) for g in entities.writer_gid_seq] == [pub.key.bytes]
        assert len(entities.reader_gid_seq) == 1
    finally:
        node.close()
        watcher.__del__()


def test_the_transport_and_domain_come_from_the_config_and_the_environment(tmp_path, monkeypatch):
    path = tmp_path / "ros2.toml"
    path.write_text(
        '[ros2]\ntransport = "dds"\ndds_peers = ["192.168.1.10"]\n[joints]\ncommand = ["joint_0"]\n'
    )
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    config = load_hardware_config(path)
    assert (config.transport, config.domain_id, config.dds_peers) == ("dds", 42, ("192.168.1.10",))
    monkeypatch.setenv("ROS_DOMAIN_ID", "robot")
    with pytest.raises(ConfigError, match="ROS_DOMAIN_ID='robot'"):
        load_hardware_config(path)
    path.write_text('[ros2]\ntransport = "fastdds"\n[joints]\ncommand = ["joint_0"]\n')
    with pytest.raises(ConfigError, match=r"transport must be one of \('zenoh', 'dds'\)"):
        load_hardware_config(path)


def test_an_interface_the_machine_lacks_is_named():
    config = HardwareConfig(transport="dds", domain_id=231, dds_interface="nosuchif0")
    with pytest.raises(ConfigError, match=r"dds_interface='nosuchif0'.*\(ip link\)"):
        DdsTransport(config, "controller")
