"""The whole pipeline on the Rizon 4 + HX5-D20 as processes on loopback, as a user runs them:
``wholehand hw-sim`` plays the arm-hand and the person, ``wholehand control`` reaches, grasps
and regulates over ROS 2 messages. Faults: the object carried out of the workspace,
the pose lost while reaching, the controller stopped by SIGTERM and killed by SIGKILL."""

from __future__ import annotations

import json
import os
import signal
import time

import pytest
from processes import interrupt, kill_running, wait_for_line, wholehand

from wholehand.ros2.rmw_zenoh import loopback_endpoint

RIG = "flexiv_rizon4_hx5_d20_right"


DDS_LOOPBACK = ("--transport", "dds", "--dds-peer", "127.0.0.1", "--dds-interface", "127.0.0.1")


def _pair(tmp_path, *sim_args: str, control_args: tuple[str, ...] = (), dds: bool = False):
    """Start the double (listening) and the controller (connecting) on a free port; over DDS
    on loopback with ``dds`` (the domain: $ROS_DOMAIN_ID)."""
    endpoint = loopback_endpoint()
    sim_link = DDS_LOOPBACK if dds else ("--listen", endpoint, "--connect")
    control_link = DDS_LOOPBACK if dds else ("--connect", endpoint, "--listen")
    sim = wholehand(
        "hw-sim", "--hand", RIG, *sim_link, "--json", str(tmp_path / "sim.json"), *sim_args
    )
    control = wholehand(
        "control", "--hand", RIG, *control_link,
        "--json", str(tmp_path / "control.json"), *control_args,
    )  # fmt: skip
    return sim, control, endpoint


def _finish(sim, control, tmp_path, stop_control: bool = True):
    """Wait for the double, then stop the controller with SIGINT; both JSON summaries."""
    _, sim_err = sim.communicate(timeout=240)
    assert sim.returncode == 0, sim_err[-3000:]
    if stop_control and control.poll() is None:
        control.send_signal(signal.SIGINT)
    _, control_err = control.communicate(timeout=60)
    assert control.returncode == 0, control_err[-3000:]
    robot = json.loads((tmp_path / "sim.json").read_text())
    ctl = json.loads((tmp_path / "control.json").read_text())
    return robot, ctl


def _stages(ctl) -> list[tuple[str, str]]:
    return [(t["source"], t["target"]) for t in ctl["loop"]["transitions"]]


@pytest.mark.parametrize("transport", ["zenoh", "dds"])
def test_the_controller_reaches_grasps_and_regulates_through_the_perturbations_over_ros2(
    tmp_path, monkeypatch, transport
):
    monkeypatch.setenv("ROS_DOMAIN_ID", str(20 + os.getpid() % 80))  # DDS: this test's alone
    sim, control, _ = _pair(tmp_path, "--seed", "0", dds=transport == "dds")
    robot, ctl = _finish(sim, control, tmp_path)
    # Real-time runs are not seeded: on failure, say what both sides saw.
    seen = robot["events"], ctl["loop"], ctl["backend"]
    assert ctl["mode"] == "pipeline"
    stages = _stages(ctl)
    assert stages[:2] == [("reach_pregrasp", "reach_grasp"), ("reach_grasp", "regulate")], seen
    # Whether the snatch takes the object, and whether the hand regrasps it before the episode
    # ends, varies between real-time runs (bench pipeline measures how often); the seeded
    # in-process episode (tests/test_reach.py) checks the regrasp itself. Here: every loss is
    # the stage machine's own verdict, a switch back to reaching with its reason.
    for i, (source, target) in enumerate(stages):
        if source == "regulate":
            assert target == "reach_pregrasp", seen
            assert ctl["loop"]["transitions"][i]["reason"].startswith("grasp lost"), seen
    assert robot["perturbations"] >= 1, seen  # the person moved the object during the reach
    assert robot["malformed_commands"] == 0 and robot["arm_messages"] > 500, seen
    # The person saw the controller's stage on its status topic, as in process.
    # The controller may outlive the double by a few messages.
    assert len(stages) < robot["status_messages"] <= ctl["backend"]["status_messages"], seen
    assert robot["max_torque_rate_Nm_s"] <= 20.0 * 1.05, seen
    guard = ctl["backend"]["guard"]
    rules = ("joints_lost", "exit", "stop", "watchdog")
    stops = sum(guard.get(rule, 0) for rule in rules)
    assert robot["stops_to_zero"] <= stops, seen  # every jump to zero is a safety rule's
    assert ctl["loop"]["n_errors"] == 0, seen
    backend = ctl["backend"]
    assert backend["arm_guard"]["ok"] > 500 and backend["guard"]["exit"] > 0, seen


def test_the_object_carried_out_of_the_workspace_sends_the_arm_home_and_back(tmp_path):
    sim, control, _ = _pair(tmp_path, "--away", "0.5", "2.5", "--duration", "6")
    robot, ctl = _finish(sim, control, tmp_path)
    seen = robot["events"], ctl["loop"]
    stages = _stages(ctl)
    went = [i for i, s in enumerate(stages) if s[1] == "home"]
    assert went and stages[went[0] + 1] == ("home", "reach_pregrasp"), seen
    back = ctl["loop"]["transitions"][went[0] + 1]
    assert "back in the workspace" in back["reason"], seen
    assert ctl["loop"]["status_counts"]["home"] > 100, seen


def test_the_pose_lost_while_reaching_holds_the_arm_then_reaching_resumes(tmp_path):
    sim, control, _ = _pair(tmp_path, "--dropout", "0.2", "0.8", "--duration", "4")
    robot, ctl = _finish(sim, control, tmp_path)
    counts = ctl["loop"]["status_counts"]
    # 0.8 s without poses less the 0.2 s timeout and the tracker's 33 ms latency: ~0.57 s held
    # (fewer cycles when a loaded machine makes some overrun). The dropout is 0.8 s of the
    # double's simulated time, which a loaded machine stretches: the bound scales with it.
    stretch = max(1.0, robot["wall_s"] / robot["duration_s"])
    assert 0.25 * 200 <= counts.get("pose_lost", 0) <= 0.7 * 200 * stretch, (counts, stretch)
    assert counts["reaching"] > counts["pose_lost"], counts  # and reaching before and after


def test_sigterm_mid_reach_ends_on_the_last_commands_and_sigkill_leaves_it_to_the_drives(
    tmp_path,
):
    """Paced by events, not by the double's clock: the double runs until the test stops it two
    seconds after the second controller is killed, so a loaded computer makes it slower, not
    red."""
    sim, control, endpoint = _pair(tmp_path, "--duration", "300")
    second = None
    try:
        wait_for_line(control, "streams up")
        # Mid-reach: the fingers close for about half a second before the hand regulates.
        wait_for_line(control, "stage reach_pregrasp -> reach_grasp")
        control.send_signal(signal.SIGTERM)
        _, err = control.communicate(timeout=30)
        assert control.returncode == 0, err[-3000:]
        ctl = json.loads((tmp_path / "control.json").read_text())
        assert ctl["loop"]["stopped_by"] == "stopped"
        assert ctl["backend"]["guard"]["exit"] > 0 and ctl["backend"]["arm_guard"]["hold"] >= 1
        # A second controller, killed: nothing is sent after it, the hand's drives time out.
        second = wholehand("control", "--hand", RIG, "--connect", endpoint, "--listen")
        wait_for_line(second, "streams up")
        wait_for_line(second, "stage reach_pregrasp -> reach_grasp")
        second.send_signal(signal.SIGKILL)
        second.wait()
        time.sleep(2.0)  # 400 cycles of the double's 200 Hz without commands
        sim_err = interrupt(sim, timeout=120)
    finally:
        kill_running(sim, control, second)
    assert sim.returncode == 130, sim_err[-3000:]  # stopped by the test, as planned
    robot = json.loads((tmp_path / "sim.json").read_text())
    assert robot["statuses"]["command_timeout"] > 100, robot["statuses"]
    assert robot["malformed_commands"] == 0


def test_a_hand_on_a_position_interface_reaches_and_then_regulates_in_torque(tmp_path):
    from wholehand.ros2.config_file import hand_hardware_config

    config = tmp_path / "position.toml"
    text = hand_hardware_config(RIG).read_text()
    topic = 'hand_position_command = "/hand_position_controller/commands"\n'
    config.write_text(text.replace("[topics]\n", "[topics]\n" + topic))
    sim, control, _ = _pair(
        tmp_path, "--config", str(config), "--duration", "4", control_args=("--config", str(config))
    )
    robot, ctl = _finish(sim, control, tmp_path)
    assert ("reach_grasp", "regulate") in _stages(ctl), ctl["loop"]
    assert robot["statuses"]["remote_position"] > 300, robot["statuses"]  # reaching: positions
    assert robot["statuses"]["remote"] > 100, robot["statuses"]  # regulating: torques
    assert robot["hand_position_messages"] > 100 and robot["malformed_commands"] == 0
