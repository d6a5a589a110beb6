"""MCAP recordings read back with an independent reader (``mcap`` + ``mcap_ros2``'s CDR decoder,
not the rosbags that wrote them) and checked against the run's own record, cycle by cycle."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path
from urllib.parse import urlparse

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from wholehand.errors import ConfigError
from wholehand.recording.mcap_recording import ARROW_SCALE, TOPICS, McapRecorder
from wholehand.recording.mcap_replay import read_mcap_record
from wholehand.trials.trial import TrialSpec, run_trial

QUICK = {"settle_time": 0.3, "load_duration": 0.1}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A short perturbation trial with the recorder beside the run's own record."""
    path = tmp_path_factory.mktemp("mcap") / "run.mcap"
    spec = TrialSpec(theta_deg=60.0, protocol_params=QUICK)
    record = run_trial(spec, observers=[McapRecorder(path, {"spec": {"hand": spec.hand}})])
    return path, record


def _read(path: Path):
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        summary = reader.get_summary()
        messages: dict[str, list] = {}
        for _, channel, message, decoded in reader.iter_decoded_messages():
            messages.setdefault(channel.topic, []).append((message.log_time, decoded))
    return header, summary, messages


def test_the_file_follows_rosbag2s_mcap_conventions(recorded):
    path, _ = recorded
    header, summary, _ = _read(path)
    assert header.profile == "ros2"
    assert {c.topic for c in summary.channels.values()} == set(TOPICS)
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg"
        assert schema.name == TOPICS[channel.topic][0]
        latched = TOPICS[channel.topic][1]
        assert f"durability: {1 if latched else 2}" in channel.metadata["offered_qos_profiles"]


def test_every_cycle_carries_the_records_state_torques_and_forces(recorded):
    path, record = recorded
    _, _, msgs = _read(path)
    n = len(record.rows["t"])
    for topic in ("/joint_states", "/tf", "/wholehand/torque_command", "/wholehand/contacts"):
        assert len(msgs[topic]) == n, topic
    names = json.loads(msgs["/wholehand/run_info"][0][1].data)["joint_names"]
    for i in (0, n // 2, n - 1):
        stamp, js = msgs["/joint_states"][i]
        assert list(js.name) == names
        np.testing.assert_array_equal(js.position, record.rows["q"][i])
        np.testing.assert_array_equal(
            msgs["/wholehand/torque_command"][i][1].data, record.rows["tau"][i]
        )
        tf = {t.child_frame_id: t.transform for t in msgs["/tf"][i][1].transforms}
        v = tf["object"].translation
        np.testing.assert_allclose([v.x, v.y, v.z], record.rows["p_object"][i], atol=1e-12)
        assert js.header.stamp.sec + 1e-9 * js.header.stamp.nanosec == pytest.approx(
            1e-9 * stamp, abs=1e-9
        )
        lines = {m.ns: m for m in msgs["/wholehand/contacts"][i][1].markers}["forces"]
        ends = np.array([[p.x, p.y, p.z] for p in lines.points]).reshape(-1, 2, 3)
        contacts = record.contacts_at(i)
        np.testing.assert_allclose(ends[:, 0], contacts["contact_p"], atol=1e-12)
        f = (ends[:, 1] - ends[:, 0]) / ARROW_SCALE
        np.testing.assert_allclose(f, contacts["contact_f"], atol=1e-9)
        w = msgs["/wholehand/residual_wrench"][i][1].wrench
        np.testing.assert_allclose(
            [w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z],
            record.rows["residual_wrench"][i],
        )
    statuses = [m.data for _, m in msgs["/wholehand/status"]]
    assert statuses[0] == f"{record.rows['stage'][0]}: {record.rows['status'][0]}"
    assert msgs["/wholehand/stage"][0][1].data == f"start: {record.rows['stage'][0]}"


def test_the_robot_description_draws_the_hand_from_files_that_exist(recorded):
    path, _ = recorded
    _, _, msgs = _read(path)
    urdf = ET.fromstring(msgs["/robot_description"][0][1].data)
    meshes = [m.get("filename", "") for m in urdf.iter("mesh")]
    assert meshes and all(Path(urlparse(uri).path).is_file() for uri in meshes)
    links = {link.get("name") for link in urdf.iter("link")}
    frames = {t.child_frame_id for t in msgs["/tf"][0][1].transforms}
    assert links <= frames  # every link of the model has its transform


def test_a_recording_reads_back_as_the_run_record(recorded):
    path, record = recorded
    again = read_mcap_record(path)
    assert again.meta["spec"]["hand"] == "allegro_right"
    assert len(again.rows["t"]) == len(record.rows["t"])
    for key in ("q", "tau", "p_object", "n_contacts", "stage", "status"):
        np.testing.assert_array_equal(np.asarray(again.rows[key]), np.asarray(record.rows[key]))
    np.testing.assert_allclose(again.rows["r_object"], record.rows["r_object"], atol=1e-9)
    i = len(record.rows["t"]) // 2
    np.testing.assert_allclose(
        again.contacts_at(i)["contact_f"], record.contacts_at(i)["contact_f"], atol=1e-9
    )


def test_reading_names_a_missing_or_foreign_file(tmp_path):
    with pytest.raises(ConfigError, match="no MCAP recording"):
        read_mcap_record(tmp_path / "none.mcap")
    from mcap.writer import Writer

    other = tmp_path / "other.mcap"
    with open(other, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2")
        writer.finish()
    with pytest.raises(ConfigError, match="no /wholehand/run_info"):
        read_mcap_record(other)


def _disk_full_after(messages: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """The recorder's writes fail as on a full disk after ``messages`` messages."""
    from wholehand.recording import mcap_recording

    calls = {"n": 0}
    write = mcap_recording.McapWriter.write

    def full_disk(self, topic, message, t):
        calls["n"] += 1
        if calls["n"] > messages:
            raise OSError(28, "No space left on device")
        write(self, topic, message, t)

    monkeypatch.setattr(mcap_recording.McapWriter, "write", full_disk)


def test_a_failing_recording_stops_itself_not_the_run(tmp_path, monkeypatch):
    _disk_full_after(50, monkeypatch)
    recorder = McapRecorder(tmp_path / "run.mcap")
    record = run_trial(TrialSpec(protocol_params=QUICK), observers=[recorder])
    assert record.meta["loop"]["n_errors"] == 0 and len(record.rows["t"]) > 100
    assert "No space left on device" in recorder.stopped and recorder.stopped.startswith("t = ")


def test_a_recording_path_that_cannot_be_written_is_named(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(ConfigError, match=r"cannot write the recording .*file/run.mcap"):
        run_trial(TrialSpec(protocol_params=QUICK), observers=[McapRecorder(blocker / "run.mcap")])


@pytest.mark.parametrize("fraction", [0.3, 0.6, 0.95])
def test_a_recording_cut_short_is_read_up_to_the_cut(recorded, tmp_path, fraction, capsys):
    """A crash or a full disk leaves no footer: the cycles before the cut read back exactly
    as they were recorded, and the reader says the file was cut."""
    from wholehand.cli.main import main

    path, record = recorded
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * fraction)])
    again = read_mcap_record(cut)
    n = len(again.rows["t"])
    assert 0 < n < len(record.rows["t"])
    assert "was cut short" in again.meta["cut_short"]
    for key in ("q", "tau", "p_object", "stage"):
        np.testing.assert_array_equal(np.asarray(again.rows[key]), np.asarray(record.rows[key][:n]))
    assert main(["view", str(cut), "--plot", str(tmp_path / "p.png")]) == 0
    assert "warning: " in capsys.readouterr().err and (tmp_path / "p.png").stat().st_size > 1000


def test_damaged_empty_foreign_and_misnamed_files_are_named(tmp_path):
    import zipfile

    from mcap.writer import Writer

    cases = {
        "empty.mcap": (b"", "is empty"),
        "garbage.mcap": (bytes(range(256)) * 8, "is no MCAP file: it starts with"),
    }
    for name, (content, message) in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(ConfigError, match=message):
            read_mcap_record(tmp_path / name)
    with zipfile.ZipFile(tmp_path / "run.mcap", "w") as z:  # a .npz run record, misnamed
        z.writestr("q.npy", b"")
    with pytest.raises(ConfigError, match="a zip or .npz file, a run record"):
        read_mcap_record(tmp_path / "run.mcap")
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as f:  # another tool's JSON-encoded recording
        writer = Writer(f)
        writer.start(profile="", library="other")
        schema = writer.register_schema(name="Foo", encoding="jsonschema", data=b"{}")
        channel = writer.register_channel(topic="/foo", message_encoding="json", schema_id=schema)
        writer.add_message(channel_id=channel, log_time=1, publish_time=1, data=b'{"a": 1}')
        writer.finish()
    with pytest.raises(ConfigError, match="no wholehand recording: its messages are not ROS 2"):
        read_mcap_record(foreign)
    cut_foreign = tmp_path / "cut_foreign.mcap"
    cut_foreign.write_bytes(foreign.read_bytes()[:-40])
    with pytest.raises(ConfigError, match="are 'json', not ROS 2 CDR"):
        read_mcap_record(cut_foreign)


def test_run_says_when_its_recording_stopped(tmp_path, monkeypatch, capsys):
    from wholehand.cli.main import main

    _disk_full_after(50, monkeypatch)
    path = tmp_path / "r.mcap"
    main(["run", "--theta", "0", "--record", str(path)])
    out = capsys.readouterr().out
    assert f"recording: {path} STOPPED at t = " in out and "No space left on device" in out


def test_the_scene_carries_the_hands_meshes_so_the_file_draws_it_alone(recorded):
    """Every contact link's mesh is a triangle list in its own frame (namespace ``hand``):
    placed by the link's transform in the file, its triangles are the link's surface where the
    model puts it, without the URDF's mesh files."""
    import pinocchio as pin

    from wholehand.models.hand import load_hand
    from wholehand.models.kinematics import HandKinematics

    path, record = recorded
    _, _, msgs = _read(path)
    hand = load_hand("allegro_right")
    markers = {
        m.header.frame_id: m for m in msgs["/wholehand/scene"][0][1].markers if m.ns == "hand"
    }
    with_faces = [n for i, n in enumerate(hand.link_names) if len(hand.link_mesh(i).faces)]
    assert sorted(markers) == sorted(with_faces)
    tf = {t.child_frame_id: t.transform for t in msgs["/tf"][0][1].transforms}
    kin = HandKinematics(hand)
    kin.update(np.asarray(record.rows["q"][0]), np.eye(4))  # the first cycle's posture
    for link in with_faces[:3]:
        i = hand.link_index(link)
        marker = markers[link]
        assert marker.type == 11 and marker.frame_locked
        mesh = hand.link_mesh(i)
        assert len(marker.points) == 3 * len(mesh.faces)
        r, v = tf[link].rotation, tf[link].translation
        R = pin.Quaternion(r.w, r.x, r.y, r.z).toRotationMatrix()
        local = np.array([[p.x, p.y, p.z] for p in marker.points])
        in_world = local @ R.T + np.array([v.x, v.y, v.z])
        corners = np.asarray(mesh.vertices)[np.asarray(mesh.faces)].reshape(-1, 3)
        joints = np.full(len(corners), int(hand.link_joint[i]), dtype=np.intp)
        base = np.eye(4)
        base[:3, :3] = pin.exp3(np.asarray(record.rows["r_base"][0]))
        base[:3, 3] = record.rows["p_base"][0]
        kin.update(np.asarray(record.rows["q"][0]), base)
        np.testing.assert_allclose(in_world, kin.transform_points(corners, joints), atol=1e-9)


def test_the_file_carries_rosbag2s_metadata_record_and_each_topics_type_hash(recorded):
    """As rosbag2 writes an MCAP bag: a metadata record ``rosbag2`` whose
    ``serialized_metadata`` (version 9) counts every topic's messages, and each channel's
    ``topic_type_hash`` (RIHS01), here against rosbags' own hash of the type."""
    from rosbags.typesys import Stores, get_typestore

    path, _ = recorded
    _, summary, msgs = _read(path)
    with open(path, "rb") as f:
        records = list(make_reader(f).iter_metadata())
    (record,) = [r for r in records if r.name == "rosbag2"]
    info = json.loads(record.metadata["serialized_metadata"])["rosbag2_bagfile_information"]
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    assert info["relative_file_paths"] == [path.name]
    counts = {
        t["topic_metadata"]["name"]: t["message_count"] for t in info["topics_with_message_count"]
    }
    assert counts == {topic: len(msgs.get(topic, [])) for topic in TOPICS}
    assert info["message_count"] == sum(counts.values())
    stamps = [t for topic in msgs for t, _ in msgs[topic]]
    assert info["starting_time"]["nanoseconds_since_epoch"] == min(stamps)
    assert info["duration"]["nanoseconds"] == max(stamps) - min(stamps)
    store = get_typestore(Stores.ROS2_JAZZY)
    for channel in summary.channels.values():
        msgtype = TOPICS[channel.topic][0]
        assert channel.metadata["topic_type_hash"] == store.hash_rihs01(msgtype)
        assert channel.metadata["topic_type_hash"].startswith("RIHS01_")


def test_a_humble_recording_carries_humbles_definitions_and_no_type_hashes(recorded, tmp_path):
    """With ``distro = "humble"`` the schemas are Humble's (its Marker lacks Jazzy's
    ARROW_STRIP constant; its fields, textures included, are the same) and nothing claims a
    type hash (Humble has none): the file decodes with its own schemas, message for message
    as the Jazzy one."""
    from rosbags.typesys import Stores, get_typestore

    path = tmp_path / "humble.mcap"
    spec = TrialSpec(theta_deg=60.0, protocol_params=QUICK)
    run_trial(spec, observers=[McapRecorder(path, {"spec": {"hand": spec.hand}}, "humble")])
    _, summary, msgs = _read(path)
    _, jazzy_summary, jazzy_msgs = _read(recorded[0])
    humble = get_typestore(Stores.ROS2_HUMBLE)
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        assert schema.data.decode() == humble.generate_msgdef(schema.name, ros_version=2)[0]
        assert "topic_type_hash" not in channel.metadata

    def marker_array(s):
        names = {x.name: x for x in s.schemas.values()}
        return names["visualization_msgs/msg/MarkerArray"].data.decode()

    assert "ARROW_STRIP" not in marker_array(summary) and "ARROW_STRIP" in marker_array(
        jazzy_summary
    )
    assert "texture_resource" in marker_array(summary)
    scene = msgs["/wholehand/scene"][0][1].markers
    jazzy_scene = jazzy_msgs["/wholehand/scene"][0][1].markers
    assert [(m.ns, m.id, len(m.points)) for m in scene] == [
        (m.ns, m.id, len(m.points)) for m in jazzy_scene
    ]
    assert len(msgs["/joint_states"]) == len(jazzy_msgs["/joint_states"])
    with open(path, "rb") as f:
        (record,) = [r for r in make_reader(f).iter_metadata() if r.name == "rosbag2"]
    info = json.loads(record.metadata["serialized_metadata"])["rosbag2_bagfile_information"]
    assert info["ros_distro"] == "humble"
    topics = info["topics_with_message_count"]
    assert all("type_description_hash" not in t["topic_metadata"] for t in topics)
