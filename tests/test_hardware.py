"""The hardware path: config, CDR messages, rmw_zenoh keys and attachments, input checks, the
safety rules, and the ros2 backend against a fake robot on loopback."""

from __future__ import annotations

import dataclasses
import os
import struct
import threading
import time
from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import pytest
from clocks import RunAheadClock
from cyclonedds._clayer import ddspy_write_ts

from wholehand.allocation.options import SolveOptions
from wholehand.errors import ConfigError
from wholehand.robot.guard import TorqueGuard
from wholehand.ros2 import messages as msgs
from wholehand.ros2.config import HardwareConfig, QoS, SafetyLimits
from wholehand.ros2.config_file import load_hardware_config, parse_hardware_config
from wholehand.ros2.inputs import JointStateReader, RejectedMessage, read_pose
from wholehand.ros2.node import open_transport
from wholehand.ros2.rmw_zenoh import (
    Attachment,
    loopback_endpoint,
    open_session,
    topic_key,
)
from wholehand.ros2.transport import SampleMeta

ALLEGRO_ORDER = tuple(f"joint_{i}.0" for i in range(16))
"""The Allegro's joints in its URDF's order (Pinocchio's model order differs)."""


# --- config -----------------------------------------------------------------------------------
def test_config_defaults_and_file(tmp_path):
    config = load_hardware_config()
    assert config.topics["torque_command"] == "/hand_effort_controller/commands"
    assert config.stamp_source == "header" and config.safety.pose_timeout == 0.2
    path = tmp_path / "hw.toml"
    path.write_text(
        '[ros2]\ndomain_id = 7\ndistro = "humble"\n[topics]\njoint_states = "/hand/joint_states"\n'
        '[qos]\nobject_pose = { reliability = "best_effort", depth = 5 }\n'
        "[safety]\npose_timeout = 0.1\n[rates]\nsync_to_joint_states = false\n"
        '[joints]\ncommand = ["a", "b"]\n'
    )
    assert load_hardware_config().sync_to_joint_states
    config = load_hardware_config(path)
    assert not config.sync_to_joint_states
    assert config.thread_priority == 0 and load_hardware_config().thread_priority == 0
    assert config.domain_id == 7 and config.topics["joint_states"] == "/hand/joint_states"
    assert config.qos_of("object_pose").reliability == "best_effort"
    assert config.safety.pose_timeout == 0.1 and config.safety.pose_ramp == 0.5


def test_the_controller_predicts_poses_unless_told_not_to():
    """[object_pose] predict: the controller's PosePredictor and its horizon; 0 turns it off."""
    from wholehand.loop.filters import PosePredictor
    from wholehand.robot.controller import pose_filters

    (predictor,) = pose_filters(load_hardware_config())
    assert isinstance(predictor, PosePredictor) and predictor.horizon == 0.1
    raw = {"joints": {"command": ["a"]}, "object_pose": {"predict": 0.05}}
    (predictor,) = pose_filters(parse_hardware_config(raw, "hw.toml"))
    assert predictor.horizon == 0.05
    raw["object_pose"] = {"predict": 0}
    assert pose_filters(parse_hardware_config(raw, "hw.toml")) == []


@pytest.mark.parametrize(
    ("raw", "named"),
    [
        ({"topic": {}}, "unknown tables ['topic']"),
        ({"ros2": {"distro": "noetic"}}, "distro 'noetic'"),
        ({"topics": {"joint_states": "joint_states"}}, "absolute ROS 2 topic name"),
        ({"topics": {"torque_command": ""}}, "torque_command must name a topic"),
        ({"qos": {"object_pose": {"reliability": "sometimes"}}}, "reliability"),
        ({"object_pose": {"stamp_source": "image"}}, "stamp_source"),
        ({"object_pose": {"predict": -0.1}}, "[object_pose] predict must be >= 0"),
        ({"safety": {"pose_timeout": -1.0}}, "pose_timeout must be > 0"),
        ({"safety": {"pose_timout": 1.0}}, "unknown keys ['pose_timout']"),
        ({"joints": {"command": ["a"], "ignore": "a"}}, "[joints] ignore must be a list"),
        ({"joints": {}}, "[joints] command is missing"),
        ({"joints": {"command": []}}, "[joints] command is empty"),
        ({"joints": {"command": ["a", "b", "a"]}}, "lists ['a'] more than once"),
        ({"rates": {"sync_to_joint_states": 1}}, "sync_to_joint_states must be true or false"),
        ({"rates": {"thread_priority": 100}}, "thread_priority must be a whole number"),
        ({"rates": {"thread_priority": -1}}, "thread_priority must be a whole number"),
        ({"rates": {"thread_priority": True}}, "thread_priority must be a whole number"),
        ({"rates": {"thread_priority": 50.0}}, "thread_priority must be a whole number"),
    ],
)
def test_config_errors_name_the_problem(raw, named):
    raw = {"joints": {"command": ["a"]}, **raw}
    with pytest.raises(ConfigError) as err:
        parse_hardware_config(raw, "hw.toml")
    assert named in str(err.value) and "hw.toml" in str(err.value)


def test_the_control_thread_runs_at_the_priority_asked_for_and_returns_after():
    """SCHED_FIFO for the calling thread inside the block, its policy back after; 0 changes
    nothing. (Runs where the test may set it: root, CAP_SYS_NICE or an rtprio limit.)"""
    import os

    from wholehand.robot.realtime import realtime_priority

    before = os.sched_getscheduler(0)
    with realtime_priority(0):
        assert os.sched_getscheduler(0) == before
    try:
        with realtime_priority(10):
            assert os.sched_getscheduler(0) == os.SCHED_FIFO
            assert os.sched_getparam(0).sched_priority == 10
    except ConfigError as err:
        pytest.skip(f"this computer refuses SCHED_FIFO: {err}")
    assert os.sched_getscheduler(0) == before


def test_the_loop_runs_on_a_frozen_heap_that_thaws_after():
    """Inside the block every object alive at its start is out of the collector's walks (a
    collection walks only newer ones); after it, they are collectable again."""
    import gc

    from wholehand.robot.realtime import frozen_heap

    assert gc.get_freeze_count() == 0
    kept = [[i] for i in range(1000)]  # containers alive before the loop
    with frozen_heap():
        frozen = gc.get_freeze_count()
        assert frozen >= len(kept)
        made = [[i] for i in range(10)]
        assert sum(map(gc.is_tracked, made)) == 10 and gc.get_freeze_count() == frozen
    assert gc.get_freeze_count() == 0 and gc.is_tracked(kept[0])


def test_a_refused_priority_names_the_fix_before_the_robot_is_commanded(monkeypatch):
    import os

    from wholehand.robot.realtime import check_priority

    def refuse(*_: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with pytest.raises(ConfigError, match=r"thread_priority = 50: .*ulimit -r 50.*CAP_SYS_NICE"):
        check_priority(50)
    check_priority(0)  # off: nothing to refuse
    with pytest.raises(ConfigError, match="0 \\(off\\) or 1-99"):
        check_priority(120)


def test_config_missing_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_hardware_config(tmp_path / "nope.toml")


# --- messages and keys ------------------------------------------------------------------------
def test_cdr_payloads_round_trip_with_the_encapsulation_header():
    payload = msgs.encode_joint_state(12.25, ["a", "b"], [0.1, 0.2], [1.0, 2.0], [])
    assert payload[:4] == b"\x00\x01\x00\x00"  # CDR, little endian
    # header.stamp follows: sec (int32) and nanosec (uint32)
    assert struct.unpack_from("<iI", payload, 4) == (12, 250_000_000)
    js = msgs.decode_joint_state(payload)
    assert js.names == ("a", "b") and js.stamp == 12.25
    np.testing.assert_array_equal(js.position, [0.1, 0.2])
    assert js.effort.shape == (0,)
    M = pin.SE3.Random().homogeneous
    pose = msgs.decode_pose(msgs.encode_pose(3.5, "world", M))
    assert pose.frame_id == "world" and pose.stamp == 3.5
    np.testing.assert_allclose(read_pose(pose, "world", 10.0), M, atol=1e-12)
    array = msgs.encode_array([1.0, -2.0])
    # data: uint32 length then float64s, 8-byte aligned after the 4-byte header
    np.testing.assert_array_equal(msgs.decode_array(array), [1.0, -2.0])
    assert struct.unpack("<dd", array[-16:]) == (1.0, -2.0)
    status = msgs.encode_string("regulate")
    # data: uint32 length with the terminating NUL, then the bytes
    assert status[4:] == struct.pack("<I", 9) + b"regulate\x00"
    assert msgs.decode_string(status) == "regulate"


def test_the_messages_code_is_generated_with_the_typestore_not_in_a_cycle(monkeypatch):
    import rosbags.serde.cdr
    import rosbags.serde.ros1

    msgs.typestore()

    def generate(*args, **kwargs):
        raise AssertionError("rosbags generated a message's code after typestore()")

    for module in (rosbags.serde.cdr, rosbags.serde.ros1):
        monkeypatch.setattr(module, "compile_lines", generate)
    msgs.decode_array(msgs.encode_array(np.zeros(16)))
    msgs.decode_joint_state(msgs.encode_joint_state(1.0, ["a"], [0.0], [0.0], [0.0]))
    msgs.decode_pose(msgs.encode_pose(1.0, "world", np.eye(4)))
    msgs.decode_string(msgs.encode_string("regulate"))


@pytest.mark.parametrize(
    "decode", [msgs.decode_joint_state, msgs.decode_pose, msgs.decode_array, msgs.decode_string]
)
def test_malformed_payloads_raise_message_error(decode):
    for payload in (b"", b"\x00\x01\x00\x00\x01", b"garbage" * 3):
        with pytest.raises(msgs.MessageError):
            decode(payload)


def test_keys_are_rmw_zenohs():
    key = topic_key(0, "/hand/joint_states", msgs.JOINT_STATE)
    assert key == (
        "0/hand/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_"
        "a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
    )
    humble = topic_key(3, "/cmd", msgs.FLOAT64_ARRAY, "humble")
    assert humble == "3/cmd/std_msgs::msg::dds_::Float64MultiArray_/TypeHashNotSupported"
    with pytest.raises(ConfigError, match="absolute"):
        topic_key(0, "cmd", msgs.FLOAT64_ARRAY)


def test_attachment_is_33_bytes_int64_int64_and_a_sized_gid():
    gid = bytes(range(16))
    data = Attachment(7, 1_700_000_000_123_456_789, gid).encode()
    assert len(data) == 33
    assert struct.unpack_from("<qq", data) == (7, 1_700_000_000_123_456_789)
    assert data[16] == 16 and data[17:] == gid  # LEB128 length, then the bytes
    assert Attachment.decode(data) == Attachment(7, 1_700_000_000_123_456_789, gid)
    with pytest.raises(msgs.MessageError):
        Attachment.decode(b"\x01\x02")


# --- incoming checks --------------------------------------------------------------------------
def _joint_msg(hand, order, q, stamp=100.0, names=None, **kw):
    names = names or [hand.joint_names[i] for i in order]
    return msgs.JointStateMsg(
        stamp,
        tuple(names),
        np.asarray(q, dtype=float)[order],
        kw.get("velocity", np.zeros(0)),
        kw.get("effort", np.zeros(0)),
    )


def test_joint_states_in_any_order_map_onto_the_model(allegro):
    reader = JointStateReader(allegro, HardwareConfig())
    q = allegro.neutral() + 0.01 * np.arange(allegro.nq)
    order = np.random.default_rng(0).permutation(allegro.nq)
    sample = reader.read(_joint_msg(allegro, order, q), now=100.0)
    np.testing.assert_array_equal(sample.q, q)
    assert sample.dq is None and sample.effort is None


def test_renamed_and_ignored_joints(allegro):
    config = HardwareConfig(rename={"joint_0.0": "hand_joint_0"}, ignore=("gripper",))
    reader = JointStateReader(allegro, config)
    names = ["hand_joint_0", *allegro.joint_names[1:], "gripper"]
    q = allegro.neutral()
    msg = msgs.JointStateMsg(1.0, tuple(names), np.r_[q, 0.5], np.zeros(0), np.zeros(0))
    np.testing.assert_array_equal(reader.read(msg, now=1.0).q, q)
    with pytest.raises(ConfigError, match="not joints of hand"):
        JointStateReader(allegro, HardwareConfig(rename={"joint_99": "x"}))


def test_a_joint_published_by_its_urdf_name_despite_a_rename_is_named_with_the_fix(allegro):
    """A robot that publishes the URDF's names to a config that renames one: the rejection says
    the name is the hand's, which name the rename expects, and where the rename is."""
    config = HardwareConfig(rename={"joint_0.0": "hand_joint_0"}, path="robot.toml")
    reader = JointStateReader(allegro, config)
    q = allegro.neutral()
    msg = msgs.JointStateMsg(1.0, tuple(allegro.joint_names), q, np.zeros(0), np.zeros(0))
    with pytest.raises(RejectedMessage) as err:
        reader.read(msg, now=1.0)
    assert err.value.reason == "unknown_joint"
    text = str(err.value)
    assert "['joint_0.0'] are joints of hand 'allegro_right'" in text
    assert "robot.toml [joints] rename expects 'joint_0.0' as 'hand_joint_0'" in text
    names = ["wrist", *allegro.joint_names[1:]]  # a name the hand does not have: the expected
    msg = msgs.JointStateMsg(1.0, tuple(names), q, np.zeros(0), np.zeros(0))
    with pytest.raises(RejectedMessage, match=r"not joints of hand .*expected: \['hand_joint_0'"):
        reader.read(msg, now=1.0)


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        ("unknown", "unknown_joint"),
        ("missing", "missing_joint"),
        ("nan", "not_finite"),
        ("short", "wrong_length"),
        ("range", "out_of_range"),
        ("future", "future_stamp"),
        ("duplicate", "duplicate_names"),
        ("velocity_nan", "not_finite"),
    ],
)
def test_bad_joint_states_are_rejected_with_a_reason(allegro, change, reason):
    reader = JointStateReader(allegro, HardwareConfig())
    q = allegro.neutral()
    names = list(allegro.joint_names)
    position, velocity, stamp = q.copy(), np.zeros(0), 100.0
    if change == "unknown":
        names[0] = "wrist"
    elif change == "missing":
        names, position = names[1:], position[1:]
    elif change == "nan":
        position[3] = np.nan
    elif change == "short":
        position = position[:-1]
    elif change == "range":
        position[2] = allegro.q_upper[2] + 1.5
    elif change == "future":
        stamp = 101.0
    elif change == "duplicate":
        names[1] = names[0]
    elif change == "velocity_nan":
        velocity = np.full(len(names), np.nan)
    msg = msgs.JointStateMsg(stamp, tuple(names), position, velocity, np.zeros(0))
    with pytest.raises(RejectedMessage) as err:
        reader.read(msg, now=100.0)
    assert err.value.reason == reason


@pytest.mark.parametrize(
    ("frame", "position", "quat", "reason"),
    [
        ("camera", [0, 0, 0], [0, 0, 0, 1], "wrong_frame"),
        ("world", [np.nan, 0, 0], [0, 0, 0, 1], "not_finite"),
        ("world", [0, 0, 0], [0, 0, 0, 2], "bad_quaternion"),
    ],
)
def test_bad_poses_are_rejected(frame, position, quat, reason):
    msg = msgs.PoseMsg(5.0, frame, np.asarray(position, float), np.asarray(quat, float))
    with pytest.raises(RejectedMessage) as err:
        read_pose(msg, "world", now=5.0)
    assert err.value.reason == reason


# --- safety rules -----------------------------------------------------------------------------
LIMITS = SafetyLimits(
    joint_timeout=0.05, pose_timeout=0.2, pose_ramp=0.5, torque_rate=2.0, watchdog=0.05
)


def test_stale_joints_hold_the_torque_then_ramp_it_by_age_then_zero():
    """The graded rule: past joint_timeout the last torque is held (the loop's, computed on a
    stale state, is not sent); past joint_hold it ramps to zero by the state's age over
    joint_ramp; past that, zero. A fresh state resumes from the torque sent last."""
    guard = TorqueGuard([0.2, 0.2], LIMITS)  # timeout 0.05, then held 0.1, ramped over 0.25
    guard.start_from(np.array([0.1, -0.1]), 0.0)
    tau, status = guard.filter(np.array([0.1, -0.1]), 0.01, joint_age=0.0, pose_age=0.0)
    assert status == "ok"
    for now, age, want, rule in [
        (0.06, 0.06, [0.1, -0.1], "joints_late"),  # a 100 ms gap keeps the grasp
        (0.11, 0.11, [0.1, -0.1], "joints_late"),
        (0.15, 0.15, [0.1, -0.1], "joints_late"),
        (0.20, 0.20, [0.08, -0.08], "joints_stale"),  # 0.05 of the 0.25 s ramp
        (0.275, 0.275, [0.05, -0.05], "joints_stale"),
        (0.40, 0.40, [0.0, 0.0], "joints_stale"),
        (0.41, 0.41, [0.0, 0.0], "joints_lost"),
    ]:
        tau, status = guard.filter(np.array([0.2, 0.2]), now, joint_age=age, pose_age=0.0)
        assert status == rule, (age, status)
        np.testing.assert_allclose(tau, want, atol=1e-12)
    tau, status = guard.filter(np.array([0.2, 0.2]), 0.42, joint_age=0.0, pose_age=0.0)
    assert status == "rate_limited"
    np.testing.assert_allclose(tau, [0.02, 0.02])  # from zero at 2 N*m/s over 10 ms
    # A short gap, then fresh states: the held torque, then regulation from it.
    guard.filter(np.array([0.05, 0.05]), 0.5, 0.0, 0.0)
    held, status = guard.filter(np.array([0.2, 0.2]), 0.58, joint_age=0.08, pose_age=0.0)
    assert status == "joints_late"
    tau, _ = guard.filter(np.array([0.2, 0.2]), 0.59, joint_age=0.0, pose_age=0.0)
    np.testing.assert_allclose(tau, held + 0.02)
    # Two gaps that fresh states ended: one past the hold (to joints_lost), one within it.
    assert guard.gaps.summary() == {
        "recovered": 2,
        "recovered_past_hold": 1,
        "longest_recovered_s": 0.41,
        "open_at_end": "",
        "open_age_s": 0.0,
    }


def test_the_gaps_leave_out_the_start_and_keep_the_gap_open_at_the_end_apart():
    """Commands before the first joint state are the start, not a gap; a gap no fresh state
    ended is the run's end (the robot stopped publishing first), reported apart from the
    gaps that ended mid-run."""
    guard = TorqueGuard([0.2, 0.2], LIMITS)
    for now in (0.0, 0.01, 0.02):
        guard.filter(np.array([0.1, 0.1]), now, joint_age=np.inf, pose_age=0.0)
    guard.filter(np.array([0.1, 0.1]), 0.03, joint_age=0.0, pose_age=0.0)
    guard.filter(np.array([0.1, 0.1]), 0.10, joint_age=0.07, pose_age=0.0)  # late, held
    guard.filter(np.array([0.1, 0.1]), 0.11, joint_age=0.0, pose_age=0.0)
    for now in (0.2, 0.3, 0.4):  # the end: no fresh state comes again
        guard.filter(np.array([0.1, 0.1]), now, joint_age=now - 0.11, pose_age=0.0)
    assert [guard.counts[k] for k in ("joints_lost", "joints_late", "joints_stale")] == [3, 2, 2]
    assert guard.gaps.summary() == {
        "recovered": 1,
        "recovered_past_hold": 0,
        "longest_recovered_s": 0.07,
        "open_at_end": "joints_stale",
        "open_age_s": 0.29,
    }


def test_no_joint_state_yet_gives_zero_torque():
    guard = TorqueGuard([0.2, 0.2], LIMITS)
    tau, status = guard.filter(np.array([0.1, -0.1]), 0.0, joint_age=np.inf, pose_age=0.0)
    assert status == "joints_lost" and not tau.any()


def test_the_stale_joint_times_are_checked():
    with pytest.raises(ConfigError, match="joint_hold must be a time >= 0"):
        SafetyLimits(joint_hold=-0.1)
    with pytest.raises(ConfigError, match="joint_ramp must be a time > 0"):
        SafetyLimits(joint_ramp=0.0)


def test_stale_pose_holds_then_ramps_to_zero_and_a_fresh_pose_resumes():
    guard = TorqueGuard([0.2, 0.2], LIMITS)
    guard.start_from(np.array([0.1, -0.05]), 0.0)
    tau, status = guard.filter(np.array([0.1, -0.05]), 0.01, 0.0, pose_age=0.1)
    assert status == "ok"
    tau, status = guard.filter(np.array([0.2, 0.2]), 1.0, 0.0, pose_age=0.21)
    assert status == "pose_stale"
    np.testing.assert_allclose(tau, [0.1, -0.05])  # held: ramp starts here
    tau, _ = guard.filter(np.array([0.2, 0.2]), 1.25, 0.0, pose_age=0.46)
    np.testing.assert_allclose(tau, [0.05, -0.025])  # halfway down the 0.5 s ramp
    tau, _ = guard.filter(np.array([0.2, 0.2]), 1.6, 0.0, pose_age=0.81)
    assert not tau.any()
    tau, status = guard.filter(np.array([0.2, 0.2]), 1.7, 0.0, pose_age=0.0)
    assert status == "rate_limited"
    np.testing.assert_allclose(tau, [0.2, 0.2])  # 0.1 s at 2 N*m/s allows the full 0.2


def test_torques_are_clamped_and_rate_limited_from_the_measured_effort():
    guard = TorqueGuard([0.2, 0.5], LIMITS)
    guard.start_from(np.array([0.05, 0.0]), 10.0)
    tau, status = guard.filter(np.array([1.0, -1.0]), 10.0, 0.0, 0.0)
    assert status == "rate_limited"
    np.testing.assert_array_equal(tau, [0.05, 0.0])  # a restart resumes where the drives are
    tau, _ = guard.filter(np.array([1.0, -1.0]), 10.01, 0.0, 0.0)
    np.testing.assert_allclose(tau, [0.07, -0.02])  # 2 N*m/s over 10 ms
    tau, status = guard.filter(np.array([1.0, -1.0]), 11.0, 0.0, 0.0)
    assert status == "clamped"
    np.testing.assert_array_equal(tau, [0.2, -0.5])


def test_a_late_command_steps_no_more_than_one_period_allows():
    """Commands at 100 Hz, one 40 ms late, then one on time 2 ms after it. The late one steps
    one period's worth, not four: a robot that measures the rate on its own clock sees no
    faster change as long as commands reach it at least a period apart, and by the commands'
    stamps (the guard's times) no pair changes faster than the limit."""
    guard = TorqueGuard([0.5], LIMITS, period=0.01)
    guard.start_from(np.zeros(1), 0.0)
    times = [0.0, 0.01, 0.05, 0.052, 0.06]
    sent = [guard.filter(np.array([0.5]), t, 0.0, 0.0)[0][0] for t in times]
    np.testing.assert_allclose(sent, [0.0, 0.02, 0.04, 0.044, 0.06])  # late: one period's step
    rates = np.diff(sent) / np.diff(times)
    assert rates.max() <= LIMITS.torque_rate * (1 + 1e-9)
    # Without the period's bound the late command would step 0.08 and then 0.004 in 2 ms.
    unbounded = TorqueGuard([0.5], LIMITS)
    unbounded.start_from(np.zeros(1), 0.0)
    late = [unbounded.filter(np.array([0.5]), t, 0.0, 0.0)[0][0] for t in times[:3]]
    np.testing.assert_allclose(late, [0.0, 0.02, 0.1])
    with pytest.raises(ConfigError, match="period must be > 0"):
        TorqueGuard([0.5], LIMITS, period=0.0)


def test_the_rate_holds_between_the_stamps_when_they_advance_less_than_the_loops_clock():
    """Commands at 100 Hz on the loop's clock whose stamps (the clock a receiver measures the
    rate by) came 10, 7 and 13 ms apart: the thread was held between reading the two clocks.
    Each step is sized by the shorter of the two intervals, so by the stamps no pair changes
    faster than the limit; unstamped commands keep the loop clock's steps."""
    times = [0.0, 0.01, 0.02, 0.03]
    stamps = [100.0, 100.01, 100.017, 100.03]
    guard = TorqueGuard([0.5], LIMITS, period=0.01)
    guard.start_from(np.zeros(1), 0.0)
    sent = [
        guard.filter(np.array([0.5]), t, 0.0, 0.0, stamp)[0][0]
        for t, stamp in zip(times, stamps, strict=True)
    ]
    np.testing.assert_allclose(sent, [0.0, 0.02, 0.034, 0.054])  # 7 ms of 2 N*m/s: 0.014
    assert (np.diff(sent) / np.diff(stamps)).max() <= LIMITS.torque_rate * (1 + 1e-9)
    assert guard.stamp_last == stamps[-1]
    unstamped = TorqueGuard([0.5], LIMITS, period=0.01)
    unstamped.start_from(np.zeros(1), 0.0)
    loop_only = [unstamped.filter(np.array([0.5]), t, 0.0, 0.0)[0][0] for t in times]
    np.testing.assert_allclose(loop_only, [0.0, 0.02, 0.04, 0.06])  # 0.02 in 7 ms by the stamps
    # A send without a stamp (or a ramp) leaves none to compare with: the loop's clock decides.
    guard.watchdog(0.04)
    assert guard.stamp_last is None


def test_watchdog_ramps_the_last_torque_to_zero():
    guard = TorqueGuard([0.2], LIMITS)
    guard.start_from(np.array([0.2]), 0.0)
    guard.filter(np.array([0.2]), 0.0, 0.0, 0.0)
    np.testing.assert_allclose(guard.watchdog(0.1), [0.2])
    np.testing.assert_allclose(guard.watchdog(0.35), [0.1])
    np.testing.assert_allclose(guard.watchdog(0.7), [0.0])
    assert guard.counts["watchdog"] == 3


# --- the ros2 backend against a fake robot ----------------------------------------------------
class FakeRobot:
    """Publishes joint states and poses, records the torque commands (one node)."""

    def __init__(self, config: HardwareConfig) -> None:
        self.transport = open_transport(config, "fake_robot")
        self.joints = self.transport.publisher("joint_states", msgs.JOINT_STATE)
        self.poses = self.transport.publisher("object_pose", msgs.POSE_STAMPED)
        self.torques: list[np.ndarray] = []
        self._sub = self.transport.subscriber(
            "torque_command",
            msgs.FLOAT64_ARRAY,
            lambda p, meta, t: self.torques.append(msgs.decode_array(p)),
        )

    def close(self) -> None:
        self.transport.close()


DDS_DOMAIN = 100 + os.getpid() % 100
"""A DDS domain of this test process alone (on loopback, unicast)."""


def loopback_configs(transport: str, **settings) -> tuple[HardwareConfig, HardwareConfig]:
    """The robot's and the controller's configs of a pair on loopback over ``transport``."""
    if transport == "dds":
        dds = {"dds_interface": "127.0.0.1", "dds_peers": ("127.0.0.1",)}
        robot = HardwareConfig(transport="dds", domain_id=DDS_DOMAIN, **dds)
        return robot, HardwareConfig(transport="dds", domain_id=DDS_DOMAIN, **dds, **settings)
    endpoint = loopback_endpoint()
    robot = HardwareConfig(listen=(endpoint,), connect=())
    return robot, HardwareConfig(connect=(endpoint,), **settings)


@pytest.fixture(params=["zenoh", "dds"])
def robot_and_backend(request, allegro):
    from wholehand_plugins.ros2_backend import Ros2Backend

    safety = SafetyLimits(
        pose_timeout=0.3, pose_ramp=0.3, torque_rate=2.0, watchdog=0.1, joint_timeout=0.5
    )
    robot_config, config = loopback_configs(
        request.param, safety=safety, command_joints=ALLEGRO_ORDER
    )
    robot = FakeRobot(robot_config)
    backend = Ros2Backend(allegro, None, config)
    yield robot, backend
    backend.close()
    robot.close()


WAIT = 5.0
"""Longest wait for messages the test sent [s] (a failure's bound, not a timing check)."""
CONNECT_ATTEMPTS = 250
"""Publications until the transport has connected (each waits up to 20 ms for an arrival)."""


def _until(condition, timeout=5.0):
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


def test_backend_reads_joints_in_any_order_and_interpolates_q_at_the_pose_stamp(
    allegro, robot_and_backend
):
    robot, backend = robot_and_backend
    order = np.arange(allegro.nq)[::-1]
    names = [allegro.joint_names[i] for i in order]
    q0, q1 = allegro.neutral(), allegro.neutral() + 0.02
    _until_connected(robot, backend, names, q0[order], stamp_age=1.0)
    t0 = time.time() - 0.05  # after the connection's samples
    wMo = pin.SE3(pin.rpy.rpyToMatrix(0.1, 0.2, 0.3), np.array([0.0, 0.05, 0.1])).homogeneous

    def publish():
        robot.joints.put(msgs.encode_joint_state(t0, names, q0[order], effort=np.zeros(16)))
        robot.joints.put(msgs.encode_joint_state(t0 + 0.02, names, q1[order]))
        robot.poses.put(msgs.encode_pose(t0 + 0.005, "world", wMo))

    joints, poses = backend.received["joint_states"], backend.received["object_pose"]
    publish()
    assert backend.streams.wait_until(
        lambda s: s.received["joint_states"] >= joints + 2 and s.received["object_pose"] > poses,
        WAIT,
    )
    obs = backend.observe()
    np.testing.assert_allclose(obs.q, q1)
    np.testing.assert_allclose(obs.wMo, wMo, atol=1e-12)
    q_then, _ = obs.q_at(obs.stamp_object)
    # Stamps since 1970 in float64 resolve ~0.2 us: 1e-5 of the 20 ms between the samples.
    np.testing.assert_allclose(q_then, q0 + 0.25 * (q1 - q0), atol=1e-6)
    np.testing.assert_allclose(obs.dq, (q1 - q0) / 0.02, rtol=1e-6)  # no velocities sent


def test_backend_rejects_bad_messages_and_keeps_the_last_good_sample(allegro, robot_and_backend):
    robot, backend = robot_and_backend
    names, q = list(allegro.joint_names), allegro.neutral()
    _until_connected(robot, backend, names, q)
    good = backend.observe()
    zenoh = robot.transport.config.transport == "zenoh"
    garbage = [
        b"\x00\x01\x00\x00 not a joint state",  # little-endian CDR's header, then garbage
        msgs.encode_joint_state(time.time(), names, q)[:40],  # truncated
        b"\x00\x00\x00\x00" + msgs.encode_joint_state(time.time(), names, q)[4:],  # big-endian
    ]
    for payload in garbage:
        if zenoh:
            robot.joints.put(payload)
        else:  # below the typed writer's own check, as a careless sender's bytes: Cyclone
            # DDS checks the CDR against the type and refuses to send it (bad parameter)
            padded = payload.ljust(-(-len(payload) // 4) * 4, b"\0")
            assert ddspy_write_ts(robot.joints.writer._ref, padded, 1) < 0  # any stamp
    bad = q.copy()
    bad[0] = np.nan
    robot.joints.put(msgs.encode_joint_state(time.time(), names, bad))
    robot.joints.put(msgs.encode_joint_state(time.time(), ["x", *names[1:]], q))
    nan_pose = np.eye(4)
    nan_pose[0, 3] = np.nan
    robot.poses.put(msgs.encode_pose(time.time(), "world", nan_pose))
    # zenoh hands the controller every payload: it decodes and counts the garbage. Cyclone DDS
    # checks each sample's CDR against the type when it is written and again on receipt, so
    # garbage never reaches the controller; well-formed bad content reaches both.
    expected = {"not_finite": 2, "unknown_joint": 1} | ({"malformed": 3} if zenoh else {})
    n = sum(expected.values())
    assert backend.streams.wait_until(lambda s: sum(s.rejected.values()) >= n, WAIT)
    assert dict(backend.rejected) == expected
    obs = backend.observe()
    np.testing.assert_array_equal(obs.q, good.q)
    assert obs.stamp_q == good.stamp_q and obs.stamp_object == good.stamp_object


def test_samples_without_rmw_zenohs_attachment_are_dropped_and_counted(allegro, robot_and_backend):
    robot, backend = robot_and_backend
    if robot.transport.config.transport != "zenoh":
        pytest.skip("rmw_zenoh's attachment is zenoh's")
    names, q = list(allegro.joint_names), allegro.neutral()
    _until_connected(robot, backend, names, q)
    good = backend.observe()
    moved = q + 0.01
    raw = robot.transport.session.declare_publisher(robot.joints.key)
    raw.put(msgs.encode_joint_state(time.time(), names, moved))  # no attachment
    raw.put(msgs.encode_joint_state(time.time(), names, moved), attachment=b"\x01\x02\x03")
    assert backend.streams.wait_until(lambda s: sum(s.rejected.values()) >= 2, WAIT)
    assert backend.rejected == {"no_attachment": 1, "bad_attachment": 1}
    np.testing.assert_array_equal(backend.observe().q, good.q)
    raw.undeclare()


def test_poses_stamped_far_behind_the_joint_states_get_the_stale_pose_rule(
    allegro, robot_and_backend
):
    from wholehand.backends.command import Command

    robot, backend = robot_and_backend
    names, q = list(allegro.joint_names), allegro.neutral()
    _until_connected(robot, backend, names, q, stamp_age=0.35)
    statuses = []
    start = time.monotonic()
    while time.monotonic() - start < 0.5:
        now = time.time()
        robot.joints.put(msgs.encode_joint_state(now, names, q))
        # A tracker that still sends, but whose images are 0.35 s old (pose_timeout 0.3 s).
        robot.poses.put(msgs.encode_pose(now - 0.35, "world", np.eye(4)))
        time.sleep(0.01)
        backend.apply(Command.torques(np.full(allegro.nv, 0.05)))
        statuses.append(backend.guard.counts["pose_stale"])
    assert backend.rejected == {} and statuses[-1] > 20


def _until_connected(robot, backend, names, q, stamp_age=0.0):
    """Publish until the backend has a joint state and a pose (the session may still be
    connecting), stamped ``stamp_age`` seconds in the past; each round waits for an arrival."""

    def connected(s) -> bool:
        return s.received["joint_states"] > 0 and s.received["object_pose"] > 0

    for _ in range(CONNECT_ATTEMPTS):
        stamp = time.time() - stamp_age
        robot.joints.put(msgs.encode_joint_state(stamp, names, q, effort=np.full(len(names), 0.1)))
        robot.poses.put(msgs.encode_pose(stamp, "world", np.eye(4)))
        if backend.streams.wait_until(connected, 0.02):
            return
    pytest.fail(f"the backend received nothing after {CONNECT_ATTEMPTS} publications")


def test_backend_starts_from_the_measured_effort_and_ramps_when_the_pose_stops(
    allegro, robot_and_backend
):
    from wholehand.backends.command import Command

    robot, backend = robot_and_backend
    names, q = list(allegro.joint_names), allegro.neutral()
    _until_connected(robot, backend, names, q)
    backend.observe()
    backend.apply(Command.torques(np.full(allegro.nv, 0.2)))
    _until(lambda: len(robot.torques) >= 1)
    np.testing.assert_allclose(robot.torques[0], 0.1)  # the drives' effort, not a jump to 0.2
    assert robot.torques[0].shape == (int(allegro.actuated_dofs.sum()),)
    # No more poses: after pose_timeout (0.3 s) the torque ramps to zero over 0.3 s.
    robot.joints.put(msgs.encode_joint_state(time.time(), names, q))
    start = time.monotonic()
    while time.monotonic() - start < 0.8:
        robot.joints.put(msgs.encode_joint_state(time.time(), names, q))
        backend.apply(Command.torques(np.full(allegro.nv, 0.2)))
        time.sleep(0.01)
    assert backend.guard.counts["pose_stale"] > 0
    _until(lambda: np.allclose(robot.torques[-1], 0.0))


def test_backend_watchdog_ramps_down_when_the_loop_stops(allegro, robot_and_backend):
    from wholehand.backends.command import Command

    robot, backend = robot_and_backend
    names, q = list(allegro.joint_names), allegro.neutral()
    _until_connected(robot, backend, names, q)
    backend.apply(Command.torques(np.full(allegro.nv, 0.1)))
    _until(lambda: len(robot.torques) >= 1)
    # The loop sends nothing more; the watchdog (0.1 s) takes over and ramps to zero (0.3 s).
    _until(lambda: backend.guard.counts["watchdog"] > 0, timeout=2.0)
    _until(lambda: np.allclose(robot.torques[-1], 0.0), timeout=2.0)
    first = robot.torques[1]
    assert np.all(first <= 0.1 + 1e-12) and np.all(first >= 0.0)


def test_a_cycle_starts_on_a_fresh_joint_state_waiting_briefly_for_one(allegro):
    """Past its start time, a cycle whose newest joint state is stale waits for the next one
    (so the torque answers a joint state just measured), at most a bounded time; a fresh one
    needs no wait. Slow streams keep the windows wide: fresh below 25 ms, waits up to 125 ms."""
    from wholehand_plugins.ros2_backend import Ros2Backend

    endpoint = loopback_endpoint()
    robot = FakeRobot(HardwareConfig(listen=(endpoint,), connect=()))
    config = HardwareConfig(
        connect=(endpoint,), joint_state_rate=10.0, control_rate=2.0, command_joints=ALLEGRO_ORDER
    )
    names, q = list(allegro.joint_names), allegro.neutral()
    clock = RunAheadClock()
    try:
        with Ros2Backend(allegro, None, config, clock=clock) as backend:
            _until_connected(robot, backend, names, q)
            clock.advance(0.1)  # the newest joint state is stale now
            stamp = time.time()
            later = msgs.encode_joint_state(stamp, names, q + 0.01)
            threading.Timer(0.02, lambda: robot.joints.put(later)).start()
            backend.step(0.0)
            assert backend.sync == {"waited": 1}
            np.testing.assert_allclose(backend.observe().q, q + 0.01)  # this cycle's sample
            backend.step(0.0)
            assert backend.sync["fresh"] == 1
            clock.advance(0.1)
            backend.step(0.0)  # nothing comes
            assert backend.sync["timed_out"] == 1
            assert backend.stats()["sync"] == {"waited": 1, "fresh": 1, "timed_out": 1}
            assert 0.0 < backend.sync_wait < 1.0
    finally:
        robot.close()
    unsynced = dataclasses.replace(config, sync_to_joint_states=False)
    with Ros2Backend(allegro, None, unsynced) as backend:
        backend.step(0.0)
        assert backend.sync == {}


def test_backend_with_no_joint_state_sends_zero_and_wait_names_the_topic(allegro):
    from wholehand_plugins.ros2_backend import Ros2Backend

    from wholehand.backends.command import Command

    endpoint = loopback_endpoint()
    config = HardwareConfig(connect=(endpoint,), command_joints=ALLEGRO_ORDER)
    with Ros2Backend(allegro, None, config) as b:
        assert np.isnan(b.observe().q).all()  # the loop's bad_state
        b.apply(Command.torques(np.full(allegro.nv, 0.2)))
        assert b.guard.counts == {"joints_lost": 1}
        with pytest.raises(ConfigError, match="no joint state on '/joint_states'.*zenoh connect"):
            b.wait_for_streams(0.1)


def test_a_silent_dds_robot_is_named_with_the_dds_settings(allegro):
    from wholehand_plugins.ros2_backend import Ros2Backend

    _, config = loopback_configs("dds", command_joints=ALLEGRO_ORDER)
    with Ros2Backend(allegro, None, config) as b:
        expected = rf"no joint state .*DDS domain {DDS_DOMAIN}, peers \['127.0.0.1'\]"
        with pytest.raises(ConfigError, match=expected):
            b.wait_for_streams(0.1)


def test_control_cli_names_a_missing_config(tmp_path, capsys):
    from wholehand.cli.main import main

    assert main(["control", "--config", str(tmp_path / "robot.toml"), "--duration", "1"]) == 2
    assert "robot.toml' does not exist" in capsys.readouterr().err


def test_shipped_config_loads_against_the_allegro_in_its_urdf_order(allegro):
    from wholehand.ros2.config_file import hand_hardware_config
    from wholehand.ros2.inputs import command_dofs

    config = load_hardware_config(hand_hardware_config("allegro_right"))
    reader = JointStateReader(allegro, config)
    # A robot publishing the URDF's names is read as it is: no rename by default.
    assert all(reader.msg_name[j] == j for j in allegro.joint_names)
    assert [allegro.joint_names[i] for i in command_dofs(allegro, config)] == list(ALLEGRO_ORDER)
    model_order = [allegro.joint_names[i] for i in np.flatnonzero(allegro.actuated_dofs)]
    assert model_order != list(ALLEGRO_ORDER)  # why the order must be given


def test_a_hand_without_a_hardware_config_is_named(tmp_path):
    from wholehand.ros2.config_file import hand_hardware_config

    with pytest.raises(ConfigError, match="no hardware config for hand 'robotis_hx5_d20_right'"):
        hand_hardware_config("robotis_hx5_d20_right")


@pytest.mark.parametrize(
    ("order", "named"),
    [
        (None, "[joints] command is missing"),
        (("wrist", *ALLEGRO_ORDER[1:]), "names ['wrist'], which are not among"),
        (ALLEGRO_ORDER[:-1], "leaves out ['joint_15.0']"),
        ((*ALLEGRO_ORDER, "joint_0.0"), "names the joints ['joint_0.0'] more than once"),
        (("hand_joint_0", *ALLEGRO_ORDER), "more than once"),  # a joint by both its names
    ],
)
def test_a_command_order_must_name_every_actuated_joint_once(allegro, order, named):
    from wholehand.ros2.inputs import command_dofs

    config = HardwareConfig(command_joints=order, rename={"joint_0.0": "hand_joint_0"})
    with pytest.raises(ConfigError) as err:
        command_dofs(allegro, config)
    assert named in str(err.value)


def test_command_order_follows_the_config_by_model_or_robot_names(allegro):
    from wholehand.ros2.inputs import command_dofs

    order = tuple(np.random.default_rng(3).permutation(ALLEGRO_ORDER))
    dofs = command_dofs(allegro, HardwareConfig(command_joints=order))
    assert [allegro.joint_names[i] for i in dofs] == list(order)
    renamed = tuple("hand_joint_0" if n == "joint_0.0" else n for n in order)
    config = HardwareConfig(command_joints=renamed, rename={"joint_0.0": "hand_joint_0"})
    np.testing.assert_array_equal(command_dofs(allegro, config), dofs)


def test_the_controller_allocator_gets_the_deadline_and_edge_screening(allegro):
    from wholehand.robot.controller import (
        AFTER_MISS,
        QP_DEADLINE,
        ControllerSpec,
        controller_allocator,
    )

    qp = controller_allocator(ControllerSpec(), allegro).options
    assert qp.deadline == QP_DEADLINE and qp.screen_edges
    assert qp.deadline_after_miss == pytest.approx(AFTER_MISS * QP_DEADLINE)
    qp = controller_allocator(ControllerSpec(qp_deadline_after_miss=0.0025), allegro).options
    assert qp.deadline_after_miss == 0.0025
    mine = ControllerSpec(allocator_params={"options": {"screen_edges": False, "deadline": 0.004}})
    qp = controller_allocator(mine, allegro).options
    assert qp.deadline == 0.004 and not qp.screen_edges  # the user's options win
    assert qp.deadline_after_miss == 0.004  # and the controller's budget after a miss with it
    mine = ControllerSpec(allocator_params={"options": {"solver": "osqp"}})
    qp = controller_allocator(mine, allegro).options
    assert qp.solver == "osqp" and qp.screen_edges and qp.deadline == QP_DEADLINE  # merged
    mine = ControllerSpec(allocator_params={"options": SolveOptions(solver="osqp")})
    qp = controller_allocator(mine, allegro).options
    assert qp == SolveOptions(solver="osqp")  # options given whole are taken as they are
    tips = controller_allocator(ControllerSpec(allocator="fingertip_only"), allegro)
    assert tips.options.screen_edges  # a QP allocator too
    feedforward = controller_allocator(ControllerSpec(allocator="feedforward"), allegro)
    assert not hasattr(feedforward, "options")  # parameters it does not take: not passed


def _parse_token(key: str) -> dict:
    """A liveliness token read as rmw_zenoh's graph cache reads it (Entity::make): 9 chunks for
    a node, 13 for a publisher or subscriber; '%' back to '/'; the QoS fields by ':' and ','."""
    parts = key.split("/")
    assert parts[0] == "@ros2_lv" and len(parts) in (9, 13) and all(parts), key
    entity = {
        "domain": int(parts[1]),
        "zid": parts[2],
        "kind": parts[5],
        "namespace": parts[7].replace("%", "/"),
        "node": parts[8].replace("%", "/"),
    }
    if len(parts) == 13:
        reliability, durability, history, deadline, lifespan, liveliness = parts[12].split(":")
        kind, depth = history.split(",")
        entity.update(
            topic=parts[9].replace("%", "/"),
            type=parts[10],
            hash=parts[11],
            qos=(int(reliability), int(durability), int(kind), int(depth)),
        )
        assert deadline.count(",") == 1 and lifespan.count(",") == 1
        assert liveliness.count(",") == 2
    return entity


def test_the_controller_declares_rmw_zenohs_liveliness_tokens(allegro):
    from wholehand_plugins.ros2_backend import NODE_NAME, Ros2Backend

    endpoint = loopback_endpoint()
    qos = {"torque_command": QoS("best_effort", "keep_last", 3)}
    config = HardwareConfig(connect=(endpoint,), command_joints=ALLEGRO_ORDER, domain_id=5, qos=qos)
    watcher = open_session(HardwareConfig(listen=(endpoint,), connect=()))
    try:
        with Ros2Backend(allegro, None, config) as backend:
            entities = []
            deadline = time.monotonic() + 5.0
            while len(entities) < 6 and time.monotonic() < deadline:
                replies = watcher.liveliness().get("@ros2_lv/**")
                entities = [_parse_token(str(r.ok.key_expr)) for r in replies if r.ok]
                time.sleep(0.05)
            zid = str(backend.transport.session.info.zid())
        by_topic = {e.get("topic"): e for e in entities}
        node = by_topic.pop(None)
        assert node == {"domain": 5, "zid": zid, "kind": "NN", "namespace": "/", "node": NODE_NAME}
        assert {t: e["kind"] for t, e in by_topic.items()} == {
            "/hand_effort_controller/commands": "MP",
            "/joint_states": "MS",
            "/object_pose": "MS",
            "/wholehand/stop": "MS",
            "/wholehand/status": "MP",
        }
        torque = by_topic["/hand_effort_controller/commands"]
        assert torque["qos"] == (2, 2, 1, 3)  # best effort, volatile, keep last 3
        assert by_topic["/joint_states"]["qos"] == (1, 2, 1, 1)
        # The token names the same type and hash as the data's key expression.
        data_key = topic_key(5, "/hand_effort_controller/commands", msgs.FLOAT64_ARRAY)
        assert data_key.split("/")[-2:] == [torque["type"], torque["hash"]]
        # Closed: the node has left the graph.
        _until(lambda: not [r for r in watcher.liveliness().get("@ros2_lv/**") if r.ok])
    finally:
        watcher.close()


@pytest.mark.parametrize("transport", ["zenoh", "dds"])
def test_the_benchmarks_link_controller_and_double_on_either_transport(transport):
    """``bench hw`` and ``bench pipeline`` take --transport: the controller's config and the
    double's arguments match (a zenoh port the double listens on, or DDS unicast on loopback)."""
    from wholehand.bench.loopback import loopback

    base = HardwareConfig(connect=("tcp/10.0.0.1:7447",), listen=("tcp/0.0.0.0:7448",))
    config, link = loopback(base, transport, ("tcp/127.0.0.1:9999",))
    assert config.transport == transport
    if transport == "dds":
        assert link[:2] == ["--transport", "dds"] and config.dds_peers == ("127.0.0.1",)
        assert config.dds_interface == "127.0.0.1"
    else:
        assert link[0] == "--listen" and link[-1] == "--connect"
        assert config.connect == (link[1],) and config.listen == ("tcp/127.0.0.1:9999",)


def test_the_double_reports_the_effort_its_motors_applied():
    """Under a position command the joint state's effort is the servo's torque, which the
    controller's first torque command starts from, not the command's zero torque."""
    from types import SimpleNamespace as Ns

    from wholehand.doubles.double import RobotPublisher

    class Put:
        def __init__(self) -> None:
            self.payloads: list[bytes] = []

        def put(self, payload: bytes, stamp_ns: int | None = None) -> int:
            self.payloads.append(payload)
            return 0

    joints, poses = Put(), Put()
    servo = np.array([0.12, -0.03])
    publisher = RobotPublisher(joints, poses, ["a", "b"], "world", "image")
    backend = Ns(time=0.0, applied_torques=lambda: servo)
    publisher.on_start(Ns(backend=backend))
    truth = Ns(stamp_q=0.5, q=np.zeros(2), dq=np.zeros(2))
    cycle = Ns(truth=truth, context=Ns(obs=Ns(wMo=None)), command=Ns(tau=np.zeros(2)))
    publisher.on_cycle(cycle)
    np.testing.assert_array_equal(msgs.decode_joint_state(joints.payloads[0]).effort, servo)
    # A backend that cannot say: the command's torque, as before.
    publisher.on_start(Ns(backend=Ns(time=0.0)))
    cycle.command.tau = np.array([0.2, 0.1])
    publisher.on_cycle(cycle)
    np.testing.assert_array_equal(msgs.decode_joint_state(joints.payloads[1]).effort, [0.2, 0.1])


def test_the_controller_publishes_its_stage_on_each_change_and_every_second():
    from wholehand.robot.controller import STATUS_PERIOD, StatusPublisher

    sent: list[str] = []
    status = StatusPublisher(sent.append)
    ran = [(0.0, "reach_grasp"), (0.005, "reach_grasp"), (STATUS_PERIOD, "reach_grasp")]
    ran += [(1.2, "regulate"), (1.205, "regulate"), (1.3, "reach_pregrasp")]
    for t, stage in ran:
        status.on_cycle(SimpleNamespace(t=t, stage=stage))
    assert sent == ["reach_grasp", "reach_grasp", "regulate", "reach_pregrasp"]


def test_the_doubles_person_sees_the_controllers_stage_and_the_contacts_before_it():
    from wholehand.doubles.episode_double import ControllerHolds

    touching = [True]
    holds = ControllerHolds(lambda cycle: touching[0])
    cycle = SimpleNamespace(t=0.0, stage="robot_double")
    meta = SampleMeta(0, bytes(16))
    assert holds(cycle)  # no status yet: the contacts decide
    holds.on_status(msgs.encode_string("reach_grasp"), meta, 0.0)
    assert not holds(cycle)  # touching, but the controller still reaches
    holds.on_status(msgs.encode_string("regulate"), meta, 0.0)
    touching[0] = False
    assert holds(cycle)
    holds.on_status(b"garbage", meta, 0.0)
    assert holds(cycle) and (holds.messages, holds.malformed) == (2, 1)


def test_the_double_withholds_joint_states_during_a_gap():
    """The robot double's publisher sends a joint state every cycle except in its gaps
    (``--joint-gap``), and counts what it withheld; bad gaps are named."""
    from types import SimpleNamespace

    from wholehand.doubles.double import DoubleSpec, RobotPublisher
    from wholehand.doubles.episode_double import EpisodeDoubleSpec

    class Sink:
        def __init__(self) -> None:
            self.sent: list[bytes] = []

        def put(self, payload: bytes, *_: object) -> None:
            self.sent.append(payload)

    joints, poses = Sink(), Sink()
    publisher = RobotPublisher(joints, poses, ["a"], "world", "image", ((0.1025, 0.05),))  # type: ignore[arg-type]
    for k in range(40):  # 0.2 s at 200 Hz
        truth = SimpleNamespace(stamp_q=k * 0.005, q=np.zeros(1), dq=np.zeros(1))
        cycle = SimpleNamespace(
            t=k * 0.005,
            truth=truth,
            context=SimpleNamespace(obs=SimpleNamespace(wMo=None)),
            command=SimpleNamespace(tau=np.zeros(1)),
        )
        publisher.on_cycle(cycle)  # type: ignore[arg-type]
    assert publisher.joint_states_withheld == 10 and len(joints.sent) == 30
    for bad in (((1.0, 0.0),), ((-0.1, 0.1),), ((float("nan"), 0.1),)):
        with pytest.raises(ConfigError, match="joint-state gap needs START >= 0"):
            DoubleSpec(joint_gaps=bad)
        with pytest.raises(ConfigError, match="joint-state gap needs START >= 0"):
            EpisodeDoubleSpec(joint_gaps=bad)


def test_the_wait_for_a_fresh_joint_state_leaves_time_for_the_cycles_computation():
    """At 200 Hz and 500 Hz the wait is at most 2 ms; after a cycle that computed 3.5 ms it is
    at most 1 ms (5 - 3.5 - 0.5), after one of 4.8 ms none (``no_time``), and a slow cycle is
    forgotten over the following ones."""
    from wholehand.ros2.joint_sync import DECAY, MARGIN, JointSync

    class Streams:
        def __init__(self) -> None:
            self.asked: list[float] = []

        def wait_for_fresh_joint(self, fresh_age: float, max_wait: float) -> tuple[str, float]:
            self.asked.append(max_wait)
            return ("timed_out", max_wait) if max_wait > 0.0 else ("timed_out", 0.0)

    now = [0.0]
    sync = JointSync(HardwareConfig(), lambda: now[0])
    streams = Streams()
    sync.wait(streams)
    assert streams.asked[-1] == pytest.approx(0.002)
    now[0] += 0.0035
    sync.computed(now[0])
    assert sync.compute_high == pytest.approx(0.0035)
    sync.wait(streams)
    assert streams.asked[-1] == pytest.approx(0.005 - 0.0035 - MARGIN)
    now[0] += 0.0048
    sync.computed(now[0])
    sync.wait(streams)
    assert streams.asked[-1] == 0.0 and sync.counts == {"timed_out": 2, "no_time": 1}
    sync.computed(now[0] + 0.0005)  # fast cycles: the slow one fades
    assert sync.compute_high == pytest.approx(0.0048 * DECAY)
    sync.computed(now[0] + 0.001)  # no wait began since: not a cycle
    assert sync.compute_high == pytest.approx(0.0048 * DECAY)
    off = JointSync(dataclasses.replace(HardwareConfig(), sync_to_joint_states=False), time.time)
    off.wait(streams)
    assert off.counts == {} and len(streams.asked) == 3
