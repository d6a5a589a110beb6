"""The ros2 backend on an arm-hand against a fake robot on loopback: the hand's PD law in torque,
the arm's targets in the controller's order (position and trajectory interfaces), the stop
topic, the last commands of every exit, and a joint state that lacks an arm joint."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from clocks import RunAheadClock

from wholehand.backends.command import Command, JointTargets
from wholehand.ros2 import messages as msgs
from wholehand.ros2.config import ArmSettings, HardwareConfig, SafetyLimits
from wholehand.ros2.rmw_zenoh import Publisher, Subscriber, loopback_endpoint, open_session

RIG = "flexiv_rizon4_hx5_d20_right"
HAND_ORDER = tuple(f"finger_r_joint{i}" for i in range(1, 21))
ARM_ORDER = tuple(f"joint{i}" for i in range(7, 0, -1))  # reversed: the order is the config's
TOPICS = {
    "joint_states": "/joint_states",
    "object_pose": "/object_pose",
    "torque_command": "/hand_effort_controller/commands",
    "arm_command": "/arm_position_controller/commands",
    "stop": "/wholehand/stop",
}


@pytest.fixture(scope="module")
def rig():
    from wholehand.models.hand import load_hand

    return load_hand(RIG)


class ArmHandRobot:
    """Publishes the rig's joint states and an object pose at 200 Hz (q, dq set by the test),
    records the torque and arm commands, and publishes stop requests."""

    def __init__(self, rig, config: HardwareConfig, q: np.ndarray, dq: np.ndarray) -> None:
        self.rig, self.q, self.dq = rig, q.copy(), dq.copy()
        self.names = list(rig.joint_names)
        self.session = open_session(config)
        self.joints = Publisher(self.session, config, "joint_states", msgs.JOINT_STATE)
        self.poses = Publisher(self.session, config, "object_pose", msgs.POSE_STAMPED)
        self.stop = Publisher(self.session, config, "stop", msgs.BOOL)
        self.torques: list[np.ndarray] = []
        self.arm: list[np.ndarray] = []
        self.trajectories: list[bytes] = []
        self.leave_out = ""
        trajectory = config.arm.interface == "trajectory"
        arm_type = msgs.JOINT_TRAJECTORY if trajectory else msgs.FLOAT64_ARRAY
        self._subs = [
            Subscriber(
                self.session,
                config,
                "torque_command",
                msgs.FLOAT64_ARRAY,
                lambda p, a, t: self.torques.append(msgs.decode_array(p)),
            ),
            Subscriber(self.session, config, "arm_command", arm_type, self._on_arm),
        ]
        self.positions: list[np.ndarray] = []
        if config.topics.get("hand_position_command"):
            self._subs.append(
                Subscriber(
                    self.session,
                    config,
                    "hand_position_command",
                    msgs.FLOAT64_ARRAY,
                    lambda p, a, t: self.positions.append(msgs.decode_array(p)),
                )
            )
        self._trajectory = trajectory
        self._running = True
        self._thread = threading.Thread(target=self._publish, daemon=True)
        self._thread.start()

    def _on_arm(self, payload, attachment, received) -> None:
        if self._trajectory:
            self.trajectories.append(payload)
            self.arm.append(msgs.decode_joint_trajectory(payload)[1])
        else:
            self.arm.append(msgs.decode_array(payload))

    def _publish(self) -> None:
        while self._running:
            keep = [i for i, n in enumerate(self.names) if n != self.leave_out]
            self.joints.put(
                msgs.encode_joint_state(
                    time.time(),
                    [self.names[i] for i in keep],
                    self.q[keep],
                    self.dq[keep],
                    np.zeros(len(keep)),
                )
            )
            self.poses.put(msgs.encode_pose(time.time(), "world", np.eye(4)))
            time.sleep(0.005)

    def close(self) -> None:
        self._running = False
        self._thread.join()
        self.session.close()


def _config(endpoint: str, connect: bool, positions: bool = False, **arm) -> HardwareConfig:
    safety = SafetyLimits(torque_rate=1e6, pose_ramp=0.2, exit_ramp=0.2, joint_timeout=0.1)
    topics = dict(TOPICS)
    if positions:
        topics["hand_position_command"] = "/hand_position_controller/commands"
    return HardwareConfig(
        connect=(endpoint,) if connect else (),
        listen=() if connect else (endpoint,),
        topics=topics,
        command_joints=HAND_ORDER,
        arm=ArmSettings(joints=ARM_ORDER, **arm),
        safety=safety,
    )


def _until(condition, timeout=5.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


@pytest.fixture
def setup(rig):
    """A robot at home with the fingers moving, and a backend connected to it (trajectory
    interface when the test is parametrised so)."""
    from wholehand_plugins.ros2_backend import Ros2Backend

    from wholehand.reaching.pipeline import grasp_hand_of, home_configuration

    made = []

    def make(positions=False, clock=time.monotonic, **arm):
        endpoint = loopback_endpoint()
        q = home_configuration(rig, grasp_hand_of(rig))
        dq = np.where(rig.arm_dofs, 0.0, 0.1 * np.arange(rig.nv))
        robot = ArmHandRobot(rig, _config(endpoint, False, positions, **arm), q, dq)
        backend = Ros2Backend(rig, None, _config(endpoint, True, positions, **arm), clock=clock)
        made.append((robot, backend))
        _until(lambda: backend.observe().stamp_q > 0.0)
        return robot, backend, q, dq

    yield make
    for robot, backend in made:
        backend.close()
        robot.close()


def _holding_and_moving(rig, q, torque: float) -> Command:
    """Every hand joint at ``torque`` [N*m], the arm's targets 0.3 rad from where it is."""
    arm = np.flatnonzero(rig.arm_dofs)
    tau = np.zeros(rig.nv)
    tau[_hand(rig)] = torque
    return Command(tau, (JointTargets(arm, q[arm] + 0.3, None, 300.0, 20.0, name="arm"),))


def _send(backend, command: Command, n: int) -> None:
    """Apply ``command`` ``n`` times, 10 ms apart."""
    for _ in range(n):
        backend.apply(command)
        time.sleep(0.01)


def _hand(rig):
    return np.flatnonzero(rig.actuated_dofs & ~rig.arm_dofs)


def _model_to_order(rig, names) -> np.ndarray:
    return np.array([rig.joint_names.index(n) for n in names])


def test_hand_targets_become_a_pd_law_in_torque_on_the_newest_joint_state(rig, setup):
    robot, backend, q, dq = setup()
    hand = _hand(rig)
    q_ref = q[hand] + 0.02 * np.sin(np.arange(hand.size))
    kp, kd = 2.0, 0.05
    tau_ff = np.zeros(rig.nv)
    tau_ff[hand] = 0.01
    tau_ff[:7] = 30.0  # an arm's feed-forward: its own controller's business, never sent
    group = JointTargets(hand, q_ref, None, kp, kd, name="fingers")
    for _ in range(2):  # the first command starts from the measured effort (zero)
        backend.apply(Command(tau_ff, (group,)))
        time.sleep(0.02)
    _until(lambda: len(robot.torques) >= 2)
    expected = np.clip(
        tau_ff[hand] + kp * (q_ref - q[hand]) - kd * dq[hand], -rig.tau_max[hand], rig.tau_max[hand]
    )
    sent = robot.torques[-1]
    order = _model_to_order(rig, HAND_ORDER)
    np.testing.assert_allclose(sent, expected[np.searchsorted(hand, order)])
    assert sent.shape == (20,)


@pytest.mark.parametrize("interface", ["position", "trajectory"])
def test_arm_targets_go_out_in_the_controllers_order_within_the_velocity_limit(
    rig, setup, interface
):
    robot, backend, q, _ = setup(interface=interface)
    arm = np.arange(7)
    goal = q[arm] + np.linspace(0.05, 0.2, 7)
    group = JointTargets(arm, goal, None, 300.0, 20.0, name="arm")
    order = _model_to_order(rig, ARM_ORDER)
    v_max = 0.5 * rig.model.velocityLimit[arm]
    stamps = []
    for _ in range(60):
        backend.apply(Command(np.zeros(rig.nv), (group,)))
        stamps.append(backend.arm_guard.t_last)
        time.sleep(0.01)
    _until(lambda: len(robot.arm) >= 60)
    sent = np.array(robot.arm)
    np.testing.assert_array_equal(sent[0], q[arm][order])  # the first: where the arm is
    steps = np.abs(np.diff(sent, axis=0))
    allowed = np.outer(np.diff(stamps), v_max[order])
    assert (steps <= allowed + 1e-12).all()
    np.testing.assert_allclose(sent[-1], goal[order])  # reached within 0.6 s
    if interface == "trajectory":
        ts = msgs.typestore()
        msg = ts.deserialize_cdr(robot.trajectories[-1], msgs.JOINT_TRAJECTORY)
        assert tuple(msg.joint_names) == ARM_ORDER
        lead = msg.points[0].time_from_start
        assert lead.sec + 1e-9 * lead.nanosec == pytest.approx(2.0 / 200.0)


def test_a_stop_freezes_the_arm_and_ramps_the_hand_to_zero_until_released(rig, setup):
    robot, backend, q, _ = setup()
    command = _holding_and_moving(rig, q, 0.1)
    _send(backend, command, 3)
    arm = np.flatnonzero(rig.arm_dofs)
    robot.stop.put(msgs.encode_bool(True))
    _until(lambda: backend.stop_requested)
    n_torque, n_arm = len(robot.torques), len(robot.arm)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 0.3:  # past the 0.2 s ramp
        backend.apply(command)
        time.sleep(0.01)
    _until(lambda: len(robot.arm) > n_arm + 20)
    frozen = np.array(robot.arm[n_arm:])
    order = _model_to_order(rig, ARM_ORDER)
    np.testing.assert_array_equal(frozen, np.tile(q[arm][order], (len(frozen), 1)))
    ramp = np.abs(np.array(robot.torques[n_torque:])).max(axis=1)
    assert (np.diff(ramp) <= 1e-12).all() and ramp[0] > 0.0 and ramp[-1] == 0.0
    robot.stop.put(msgs.encode_bool(False))
    _until(lambda: not backend.stop_requested)
    backend.apply(command)
    backend.apply(command)
    assert backend.stats()["stops"] == 1
    assert backend.guard.counts["stop"] > 0 and backend.arm_guard.counts["hold"] == 1


def test_every_exit_holds_the_arm_and_ramps_the_hand_torques_to_zero(rig, setup):
    robot, backend, q, _ = setup()
    command = _holding_and_moving(rig, q, 0.15)
    _send(backend, command, 10)
    arm = np.flatnonzero(rig.arm_dofs)
    _until(lambda: len(robot.arm) >= 10)
    n_torque, n_arm = len(robot.torques), len(robot.arm)
    started = time.monotonic()
    backend.close()
    took = time.monotonic() - started
    _until(lambda: len(robot.arm) >= n_arm + 2)
    order = _model_to_order(rig, ARM_ORDER)
    for held in robot.arm[n_arm:]:  # the arm's target: where it is, at the ramp's start and end
        np.testing.assert_array_equal(held, q[arm][order])
    _until(lambda: robot.torques and not robot.torques[-1].any())
    ramp = np.abs(np.array(robot.torques[n_torque:])).max(axis=1)
    assert ramp[0] > 0.0 and (np.diff(ramp) <= 1e-12).all() and ramp[-1] == 0.0
    assert len(ramp) >= 10 and took >= 0.2  # at the control rate over exit_ramp
    assert backend.guard.counts["exit"] == len(ramp)


def test_a_joint_state_without_an_arm_joint_holds_then_stops_the_hand_and_holds_the_arm(rig, setup):
    """Joint states rejected (an arm joint missing): past joint_timeout (0.1 s here) the hand's
    last torque is held for joint_hold (0.1 s), then ramped to zero over joint_ramp (0.25 s);
    the arm's last target is sent again throughout."""
    clock = RunAheadClock()
    robot, backend, q, _ = setup(clock=clock)
    command = _holding_and_moving(rig, q, 0.1)
    _send(backend, command, 5)
    last_target = backend.arm_guard.last.copy()
    held = robot.torques[-1].copy()
    robot.leave_out = "joint3"
    _until(lambda: backend.rejected["missing_joint"] > 0)
    order = _model_to_order(rig, ARM_ORDER)
    sent = []
    for advance, rule in [(0.15, "joints_late"), (0.35, "joints_lost")]:
        clock.advance(advance)  # the last good joint state: 0.15 s, then 0.5 s old
        n_torque, n_arm = len(robot.torques), len(robot.arm)
        backend.apply(command)
        _until(lambda n_t=n_torque, n_a=n_arm: len(robot.torques) > n_t and len(robot.arm) > n_a)
        np.testing.assert_array_equal(robot.arm[-1], last_target[order])
        assert backend.guard.counts[rule] >= 1
        sent.append(robot.torques[-1].copy())
    np.testing.assert_array_equal(sent[0], held)  # 0.15 s: the grasp's torque, held
    assert not sent[1].any()  # 0.5 s: past the ramp, zero
    assert "joint3" in backend.last_rejection


def test_a_hand_on_a_position_interface_gets_targets_while_reaching_torques_while_regulating(
    rig, setup
):
    robot, backend, q, _ = setup(positions=True)
    hand = _hand(rig)
    order = _model_to_order(rig, HAND_ORDER)
    q_ref = q.copy()
    q_ref[hand] += 0.05
    q_ref[hand[0]] = rig.q_upper[hand[0]] + 0.5  # beyond the limit: clamped
    reaching = Command(np.zeros(rig.nv), (JointTargets(hand, q_ref[hand], None, 2.0, 0.05),))
    n_torque = len(robot.torques)
    for _ in range(3):
        backend.apply(reaching)
        time.sleep(0.01)
    _until(lambda: len(robot.positions) >= 3)
    expected = np.minimum(q_ref, rig.q_upper)[order]
    np.testing.assert_allclose(robot.positions[-1], expected)
    assert len(robot.torques) == n_torque  # no torque while the hand servoes positions
    regulating = np.zeros(rig.nv)
    regulating[hand] = 0.1
    backend.apply(Command.torques(regulating))
    backend.apply(Command.torques(regulating))
    _until(lambda: len(robot.torques) >= n_torque + 2)
    np.testing.assert_array_equal(robot.torques[-1], 0.1)  # from the measured effort (zero)
    backend.apply(reaching)
    backend.close()  # the last command of a hand servoing positions: where it is
    sent = backend.stats()["hand_position_messages"]
    _until(lambda: len(robot.positions) == sent)
    np.testing.assert_allclose(robot.positions[-1], q[order])
    np.testing.assert_allclose(robot.positions[-2], expected)
