"""The rules a robot adds to the stage machine and the arm's safety rules, on constructed
states of the Rizon 4 + HX5-D20: the workspace (home, the palm's box), the pose lost while
reaching, the home stage, and the arm guard's limits against Pinocchio's own kinematics."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from wholehand.backends.observation import JointHistory, Observation
from wholehand.errors import ConfigError
from wholehand.loop.stage import CycleContext
from wholehand.models.kinematics import HandKinematics
from wholehand.reaching.base import Reacher, ReachTargets
from wholehand.reaching.home import HOME_DWELL, HOME_SPEED, HomeStage
from wholehand.reaching.pipeline import grasp_hand_of, grasp_plans, home_configuration
from wholehand.reaching.stages import HOME, PREGRASP, ReachPlanner, ReachStage
from wholehand.reaching.workspace import Box, Workspace
from wholehand.robot.arm_guard import ArmGuard
from wholehand.ros2.config_file import parse_hardware_config

RIG = "flexiv_rizon4_hx5_d20_right"
HELD_AT = np.array([0.45, 0.0, 0.25])
"""Where the episode's person holds the object for an arm [m]."""


@pytest.fixture(scope="module")
def rig():
    from wholehand.models.hand import load_hand

    return load_hand(RIG)


@pytest.fixture(scope="module")
def cube():
    from wholehand.models.object_catalogue import load_object

    return load_object("077_rubiks_cube")


@pytest.fixture(scope="module")
def q_home(rig):
    return home_configuration(rig, grasp_hand_of(rig))


def workspace(palm=((0.1, -0.5, 0.05), (0.85, 0.5, 0.8))) -> Workspace:
    return Workspace(Box(*palm), Box((0.2, -0.4, 0.05), (0.75, 0.4, 0.6)))


def pose(p) -> np.ndarray:
    M = np.eye(4)
    M[:3, 3] = p
    return M


def context(hand, q, wMo, t=1.0, pose_age=0.0) -> CycleContext:
    obs = Observation(
        q, np.zeros(hand.nv), hand.wMb, t, wMo, t - pose_age, JointHistory(hand.nq, 4)
    )
    return CycleContext(t, 0.005, obs, hand, None, HandKinematics(hand), HandKinematics(hand))


class Recorder(Reacher):
    """Stands still and keeps the targets it was given."""

    def __init__(self) -> None:
        self.targets: list[ReachTargets] = []

    def step(self, q, wMb, wMo, targets, dt):
        self.targets.append(targets)
        return q.copy(), wMb.copy()


class NoContacts:
    def estimate(self, kinematics, wMo, stamp=0.0):
        raise AssertionError("the pre-grasp stage estimates no contacts")


def reach_stage(rig, cube, robot_workspace, pose_timeout=0.2):
    grasp_hand = grasp_hand_of(rig)
    planner = ReachPlanner(grasp_plans(grasp_hand, cube), usable=lambda p, w: True)
    reacher = Recorder()
    stage = ReachStage(
        rig,
        reacher,
        planner,
        NoContacts(),  # type: ignore[arg-type]
        "pregrasp",
        grasp_hand=grasp_hand,
        workspace=robot_workspace,
        pose_timeout=pose_timeout,
    )
    return stage, reacher


def servo_target(out) -> np.ndarray:
    (group,) = out.command.targets
    return group.q


# --- the reaching stages on a robot -----------------------------------------------------------
def test_an_object_outside_the_workspace_sends_the_arm_home_held_where_it_is(rig, cube, q_home):
    stage, reacher = reach_stage(rig, cube, workspace())
    inside = context(rig, q_home, pose(HELD_AT))
    stage.start(inside)
    assert stage.step(inside).next is None and len(reacher.targets) == 1
    q_now = q_home + 0.01
    out = stage.step(context(rig, q_now, pose(HELD_AT + [0.0, 0.6, 0.0])))
    assert out.next == HOME and out.status == "out_of_workspace"
    np.testing.assert_array_equal(servo_target(out), q_now)  # held: no reacher step
    assert len(reacher.targets) == 1


def test_a_lost_pose_holds_the_arm_and_fingers_until_a_fresh_pose(rig, cube, q_home):
    stage, reacher = reach_stage(rig, cube, workspace(), pose_timeout=0.2)
    fresh = context(rig, q_home, pose(HELD_AT))
    stage.start(fresh)
    stage.step(fresh)
    just_fresh = stage.step(context(rig, q_home, pose(HELD_AT), pose_age=0.19))
    assert just_fresh.status == "reaching"
    lost = stage.step(context(rig, q_home + 0.02, pose(HELD_AT), pose_age=0.21))
    assert lost.status == "pose_lost" and lost.next is None
    np.testing.assert_array_equal(servo_target(lost), q_home + 0.02)
    # Still lost a cycle later with the arm elsewhere: held at the first lost cycle's angles.
    later = stage.step(context(rig, q_home + 0.05, pose(HELD_AT), pose_age=0.3))
    np.testing.assert_array_equal(servo_target(later), q_home + 0.02)
    assert len(reacher.targets) == 2
    back = stage.step(context(rig, q_home, pose(HELD_AT)))
    assert back.status == "reaching" and len(reacher.targets) == 3


def test_the_palm_target_is_moved_into_the_palm_box_with_the_fingertips(rig, cube, q_home):
    free, free_reacher = reach_stage(rig, cube, workspace())
    ctx = context(rig, q_home, pose(HELD_AT))
    free.start(ctx)
    free.step(ctx)
    wanted = free_reacher.targets[-1].links
    palm = wanted[rig.palm_link][:3, 3]
    # A palm box whose floor lies 5 cm above the palm's target: the targets rise together.
    floor = palm[2] + 0.05
    boxed, reacher = reach_stage(rig, cube, workspace(((-1, -1, floor), (1, 1, 1.5))))
    boxed.start(ctx)
    boxed.step(ctx)
    moved = reacher.targets[-1].links
    assert moved[rig.palm_link][2, 3] == pytest.approx(floor)
    for link, target in wanted.items():
        np.testing.assert_allclose(moved[link][:3, 3] - target[:3, 3], [0.0, 0.0, floor - palm[2]])
        np.testing.assert_array_equal(moved[link][:3, :3], target[:3, :3])
    assert boxed.palm_clamped == 1 and free.palm_clamped == 0


# --- the home stage -----------------------------------------------------------------------------
def test_home_moves_at_home_speed_and_returns_after_the_dwell_with_fresh_poses(rig, q_home):
    stage = HomeStage(rig, q_home, workspace(), pose_timeout=0.2)
    q0 = q_home.copy()
    q0[:7] += np.array([0.3, -0.3, 0.001, 0.0, 0.2, 0.0, -0.1])
    away = pose(HELD_AT + [0.0, 0.6, 0.0])
    ctx = context(rig, q0, away, t=0.0)
    stage.start(ctx)
    out = stage.step(ctx)
    step = HOME_SPEED * 0.005
    np.testing.assert_allclose(servo_target(out), q0 + np.clip(q_home - q0, -step, step))
    assert out.status == "home" and out.next is None
    t, outs = 0.0, []
    while t < 2 * HOME_DWELL:  # back in the box but the pose is stale: stays home
        t += 0.005
        outs.append(stage.step(context(rig, q0, pose(HELD_AT), t=t, pose_age=0.3)))
    assert all(o.next is None for o in outs)
    start = t + 0.005
    while True:
        t += 0.005
        out = stage.step(context(rig, q0, pose(HELD_AT), t=t))
        if out.next is not None:
            break
    assert out.next == PREGRASP and t - start == pytest.approx(HOME_DWELL, abs=0.006)


def test_home_refuses_a_hand_without_an_arm(allegro):
    with pytest.raises(ConfigError, match="has no arm"):
        HomeStage(allegro, allegro.neutral(), workspace(), pose_timeout=0.2)


# --- the arm guard ------------------------------------------------------------------------------
def palm_by_pinocchio(rig, q) -> np.ndarray:
    data = rig.model.createData()
    pin.framesForwardKinematics(rig.model, data, q)
    return data.oMf[rig.model.getFrameId(rig.palm_link)].translation.copy()


def test_arm_targets_move_from_the_measured_position_within_the_velocity_limit(rig, q_home):
    guard = ArmGuard(rig, 0.5, None)
    arm = guard.q_index
    first, status = guard.filter(q_home[arm] + 0.5, q_home, now=0.0)
    np.testing.assert_array_equal(first, q_home[arm])  # the first target: where the arm is
    assert status == "velocity_limited"
    second, _ = guard.filter(q_home[arm] + 0.5, q_home, now=0.01)
    v_max = 0.5 * rig.model.velocityLimit[guard.dofs]
    np.testing.assert_allclose(second, q_home[arm] + 0.01 * v_max)
    held, status = guard.filter(second, q_home, now=0.02)
    assert status == "ok"
    np.testing.assert_array_equal(held, second)


def test_arm_targets_stay_within_the_joint_limits(rig, q_home):
    guard = ArmGuard(rig, 1.0, None)
    arm = guard.q_index
    upper = rig.q_upper[arm]
    q = q_home.copy()
    q[arm] = upper - 0.001
    guard.hold(q, now=0.0)
    out, status = guard.filter(upper + 1.0, q, now=10.0)
    assert status == "position_limited"
    np.testing.assert_array_equal(out, upper)


def test_a_target_that_takes_the_palm_out_of_its_box_is_not_sent(rig, q_home):
    palm = palm_by_pinocchio(rig, q_home)
    box = Box(tuple(palm - 0.05), tuple(palm + 0.05))
    guard = ArmGuard(rig, 1.0, box)
    arm = guard.q_index
    guard.hold(q_home, now=0.0)
    near = q_home[arm].copy()
    near[0] += 0.01  # the base joint turns the palm by ~5 mm: inside
    q = q_home.copy()
    q[arm] = near
    assert box.contains(palm_by_pinocchio(rig, q))
    out, status = guard.filter(near, q_home, now=1.0)
    assert status == "ok"
    far = near.copy()
    far[0] += 0.3  # ~13 cm: outside
    q[arm] = far
    assert not box.contains(palm_by_pinocchio(rig, q))
    out, status = guard.filter(far, q_home, now=2.0)
    assert status == "workspace"
    np.testing.assert_array_equal(out, near)
    assert dict(guard.counts) == {"hold": 1, "ok": 1, "workspace": 1}
    # Held targets are answered from the last check; the fingers do not move the palm.
    fingers = q_home.copy()
    fingers[~np.isin(np.arange(rig.nq), arm)] += 0.2
    for target, inside in ((far, False), (near, True), (near, True), (far, False)):
        assert guard.palm_inside(target, fingers) is inside


# --- the config of an arm -----------------------------------------------------------------------
ARM = {
    "topics": {"arm_command": "/arm_position_controller/commands"},
    "joints": {"command": ["a"]},
    "arm": {"joints": [f"joint{i}" for i in range(1, 8)]},
    "workspace": {
        "palm_min": [0, 0, 0],
        "palm_max": [1, 1, 1],
        "object_min": [0, 0, 0],
        "object_max": [1, 1, 1],
    },
}


def changed(path: str, value) -> dict:
    raw = {k: dict(v) for k, v in ARM.items()}
    table, key = path.split(".")
    if value is None:
        raw[table].pop(key)
    else:
        raw[table][key] = value
    return raw


@pytest.mark.parametrize(
    ("raw", "named"),
    [
        (changed("arm.joints", None), "[arm] joints is missing"),
        (changed("arm.interface", "velocity"), "[arm] interface must be"),
        (changed("arm.velocity_scale", 1.5), "velocity_scale must be in (0, 1]"),
        (changed("arm.home", [0.0, 1.0]), "[arm] home has 2 values for 7 joints"),
        (changed("arm.joints", ["joint1", "joint1"]), "lists ['joint1'] more than once"),
        ({k: v for k, v in ARM.items() if k != "workspace"}, "[workspace] is missing"),
        (changed("workspace.palm_max", None), "needs palm_min and palm_max"),
        (changed("workspace.object_max", [1, 1, -1]), "lower bound must be below"),
        (changed("topics.arm_command", ""), "[arm] is set but [topics] arm_command is not"),
    ],
)
def test_arm_config_errors_name_the_key(raw, named):
    with pytest.raises(ConfigError) as err:
        parse_hardware_config(raw, "robot.toml")
    assert named in str(err.value) and "robot.toml" in str(err.value)


def test_the_arm_command_must_name_every_arm_joint_once(rig):
    from wholehand.ros2.inputs import arm_command_dofs

    config = parse_hardware_config(changed("arm.joints", [f"joint{i}" for i in range(7, 0, -1)]))
    dofs = arm_command_dofs(rig, config)
    assert [rig.joint_names[i] for i in dofs] == [f"joint{i}" for i in range(7, 0, -1)]
    short = parse_hardware_config(changed("arm.joints", [f"joint{i}" for i in range(1, 7)]))
    with pytest.raises(ConfigError, match=r"leaves out \['joint7'\]"):
        arm_command_dofs(rig, short)


def test_the_shipped_arm_config_loads_against_the_rig(rig):
    from wholehand.ros2.config_file import hand_hardware_config, load_hardware_config
    from wholehand.ros2.inputs import arm_command_dofs, command_dofs

    config = load_hardware_config(hand_hardware_config(RIG))
    assert config.workspace is not None and config.workspace.object.contains(HELD_AT)
    hand_joints = [rig.joint_names[i] for i in command_dofs(rig, config)]
    assert hand_joints == [f"finger_r_joint{i}" for i in range(1, 21)]
    assert list(arm_command_dofs(rig, config)) == list(range(7))


def test_table_one_columns_are_counted_from_the_stage_transitions():
    from wholehand.bench.pipeline import _outcome

    def switch(t, source, target):
        return {"t": t, "source": source, "target": target, "reason": ""}

    transitions = [
        switch(101.0, "reach_pregrasp", "reach_grasp"),
        switch(101.5, "reach_grasp", "regulate"),
        switch(105.0, "regulate", "reach_pregrasp"),  # lost ...
        switch(105.2, "reach_pregrasp", "home"),  # ... out of the workspace
        switch(107.0, "home", "reach_pregrasp"),
        switch(107.5, "reach_grasp", "regulate"),  # regrasped 2.5 s after the loss
        switch(109.0, "regulate", "reach_pregrasp"),  # lost for good
    ]
    row = _outcome(transitions, 100.0, complete=False, perturbations=4)
    assert row["acquired"] and row["time_to_grasp_s"] == pytest.approx(1.5)
    assert row["losses"] == 2 and row["regrasps"] == 1 and row["returns_home"] == 1
    assert row["time_to_regrasp_s"] == [pytest.approx(2.5)]
    assert _outcome([], 0.0, False, 0)["acquired"] is False


def test_table_one_totals_keep_the_largest_torque_rate_the_drives_measured():
    """Over ROS 2 each episode's row has the double's largest measured torque rate; the totals
    keep the largest of them (the in-process rows have none: None)."""
    from wholehand.bench.pipeline import _outcome, _totals

    def row(rate: float | None = None) -> dict:
        base = {**_outcome([], 0.0, False, 0), "cycle_ms": {"p50": 0.8, "p99": 2.0}}
        base["overruns"] = 0
        return base if rate is None else {**base, "max_torque_rate_Nm_s": rate}

    assert _totals([row(12.5), row(19.75), row(3.0)])["max_torque_rate_Nm_s"] == 19.75
    assert _totals([row(), row()])["max_torque_rate_Nm_s"] is None


def test_the_late_cycles_totals_say_where_each_late_cycles_time_went():
    """A cycle that alone took more than its period, one that did only with the joint-state
    wait before it, one that did neither (its time went elsewhere), over two episodes."""
    from wholehand.bench.pipeline import _late_summary

    def late(stage: str, cycle: float, wait: float, collections: int = 0) -> dict:
        return {
            "stage": stage, "status": "ok", "period_s": 0.005, "cycle_s": cycle,
            "joint_wait_s": wait, "collections": collections,
        }  # fmt: skip

    summary = _late_summary(
        [
            late("regulate", 0.0061, 0.0),
            late("regulate", 0.004, 0.0015, 1),
            late("home", 0.001, 0.0),
        ]
    )
    assert summary["kept"] == 3
    assert summary["by_stage"] == {"regulate/ok": 2, "home/ok": 1}
    assert summary["cycle_over_period"] == 1
    assert summary["wait_and_cycle_over_period"] == 1
    assert summary["elsewhere"] == 1
    assert summary["with_collection"] == 1 and summary["cycle_s_max"] == 0.0061
    assert _late_summary([])["kept"] == 0 and _late_summary([])["cycle_s_max"] is None
