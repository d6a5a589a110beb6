"""Reaching: the mink reacher against reachable targets and the table, pre-grasp clearance, the
stage machine's transitions on constructed states (and not on their near misses), the table and
the floating wrist in MuJoCo, and one seeded episode that grasps, loses and regrasps."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from wholehand import registry
from wholehand.backends.command import Command
from wholehand.backends.observation import JointHistory, Observation
from wholehand.backends.table import Table
from wholehand.contacts.base import ContactEstimator
from wholehand.errors import ConfigError
from wholehand.grasps.generate import style_arrays
from wholehand.grasps.store import load_grasps
from wholehand.loop.grasp_loss import GraspLossCheck
from wholehand.loop.stage import CycleContext, Stage, StageOutput
from wholehand.models.kinematics import HandKinematics, lowest_point
from wholehand.models.resting import resting_pose
from wholehand.reaching.base import Reacher, ReachTargets
from wholehand.reaching.pregrasp import GraspPlan, nearest_plan, plan_pregrasp
from wholehand.reaching.stages import (
    GRASP,
    PREGRASP,
    REGULATE,
    HoldStage,
    ReachPlanner,
    ReachStage,
)

OBJECT = "077_rubiks_cube"

UP = np.array([0.0, 0.0, 1.0])
"""The object frame's z up: the object rests as its mesh was modelled."""


@pytest.fixture(scope="module")
def cube(allegro):
    from wholehand.models.object_catalogue import load_object

    return load_object(OBJECT)


@pytest.fixture(scope="module")
def plans(allegro, cube) -> list[GraspPlan]:
    q_open = style_arrays(allegro, allegro.config.grasp_styles["power"])[0]
    found = [plan_pregrasp(allegro, cube, g, q_open) for g in load_grasps(allegro.name, OBJECT)]
    return [p for p in found if p is not None]


def tip_and_palm_poses(hand, q, wMb) -> dict[str, np.ndarray]:
    kin = HandKinematics(hand)
    kin.update(q, wMb)
    links = [hand.palm_link] + [f[-1] for f in hand.config.fingers.values()]
    return {link: kin.frame_pose(link) for link in links}


# --- the reacher --------------------------------------------------------------------------------
def test_reacher_brings_palm_and_fingertips_to_reachable_targets(allegro, cube) -> None:
    # Targets are the links of a known configuration, so the IK can meet them exactly.
    reacher = registry.load("reachers", "mink", hand=allegro, obj=cube, table=None)
    q_goal = np.clip(allegro.neutral() + 0.3, allegro.q_lower, allegro.q_upper)
    wMb_goal = np.eye(4)
    wMb_goal[:3, 3] = [0.0, 0.0, 0.5]
    targets = tip_and_palm_poses(allegro, q_goal, wMb_goal)
    far_object = np.eye(4)
    far_object[:3, 3] = [1.0, 1.0, 1.0]
    q, wMb = allegro.neutral(), wMb_goal.copy()
    wMb[:3, 3] += [0.08, -0.05, 0.1]
    goal = ReachTargets(targets, q_goal, allegro.palm_link)
    for _ in range(300):
        q, wMb = reacher.step(q, wMb, far_object, goal, 0.005)
    reached = tip_and_palm_poses(allegro, q, wMb)
    for link, target in targets.items():
        assert np.linalg.norm(reached[link][:3, 3] - target[:3, 3]) < 2e-3, link


def test_reacher_keeps_the_hand_above_the_table(allegro, cube) -> None:
    # The palm is sent 5 cm below the table top; every surface sample stops above it, at the
    # reacher's 5 mm clearance (a parallel palm face once sank 7.5 mm: one witness per pair).
    table = Table(top=0.0)
    reacher = registry.load("reachers", "mink", hand=allegro, obj=cube, table=table)
    q = allegro.neutral()
    wMb = np.eye(4)
    wMb[:3, 3] = [0.0, 0.0, 0.2]
    below = wMb.copy()
    below[2, 3] = -0.05
    targets = tip_and_palm_poses(allegro, q, below)
    far_object = np.eye(4)
    far_object[:3, 3] = [1.0, 1.0, 1.0]
    lowest = np.inf
    for _ in range(300):
        q, wMb = reacher.step(
            q, wMb, far_object, ReachTargets(targets, q, allegro.palm_link), 0.005
        )
        lowest = min(lowest, lowest_point(allegro, q, wMb))
    assert 0.004 < lowest < 0.006, lowest  # came down to the clearance, never closer


class RowLimit:
    """One inequality row ``sign * dq[dof] <= h`` of a mink limit."""

    def __init__(self, nv: int, dof: int, sign: float, h: float) -> None:
        self.G = np.zeros((1, nv))
        self.G[0, dof] = sign
        self.h = np.array([h])

    def compute_qp_inequalities(self, configuration, dt):
        import mink

        return mink.limits.Constraint(G=self.G.copy(), h=self.h.copy())


def test_limits_with_no_common_solution_hold_their_violations(allegro, cube, monkeypatch) -> None:
    """A finger joint that one limit says must turn back (a violation to undo) and another says
    cannot (at its range's end): the step holds the violation instead (``relaxed``) and the
    other joints still move; where no step is found at all, the hand stays (``held``)."""
    import mink
    from wholehand_plugins.reach_limits import HeldViolations

    reacher = registry.load("reachers", "mink", hand=allegro, obj=cube, table=None)
    joint = 3  # a finger joint: q[joint] turns IK dof reacher._dof[joint]
    nv, dof = reacher.model.nv, int(reacher._dof[joint])
    undo, blocked = RowLimit(nv, dof, 1.0, -0.5), RowLimit(nv, dof, -1.0, 0.0)
    held = HeldViolations(undo).compute_qp_inequalities(reacher.configuration, 0.005)
    np.testing.assert_array_equal(held.G, undo.G)
    np.testing.assert_array_equal(held.h, [0.0])
    reacher.limits += [undo, blocked]
    q0 = allegro.neutral()
    wMb = np.eye(4)
    wMb[:3, 3] = [0.0, 0.0, 0.5]
    goal = ReachTargets(tip_and_palm_poses(allegro, q0 + 0.2, wMb), q0 + 0.2, allegro.palm_link)
    far_object = np.eye(4)
    far_object[:3, 3] = [1.0, 1.0, 1.0]
    with pytest.raises(mink.NoSolutionFound):
        mink.solve_ik(reacher.configuration, [], 0.005, "daqp", limits=reacher.limits)
    q, _ = reacher.step(q0, wMb, far_object, goal, 0.005)
    assert reacher.fault_counts() == {"relaxed": 1}
    moved = np.abs(q - q0)
    assert moved[joint] < 1e-9 and moved.max() > 1e-4

    def no_solution(*args, **kwargs):
        raise mink.NoSolutionFound("daqp")

    monkeypatch.setattr(mink, "solve_ik", no_solution)
    q_held, wMb_held = reacher.step(q0, wMb, far_object, goal, 0.005)
    assert reacher.fault_counts() == {"relaxed": 1, "held": 1}
    np.testing.assert_allclose(q_held, q0, atol=1e-12)
    np.testing.assert_allclose(wMb_held, wMb, atol=1e-12)


def test_tip_weight_rises_from_far_to_near(allegro, cube) -> None:
    reacher = registry.load(
        "reachers", "mink", hand=allegro, obj=cube, near=0.03, far=0.15, tip_weight_far=0.05
    )
    assert reacher.tip_weight(0.5) == pytest.approx(0.05)
    assert reacher.tip_weight(0.15) == pytest.approx(0.05)
    assert reacher.tip_weight(0.09) == pytest.approx(0.05 + 0.5 * 0.95)
    assert reacher.tip_weight(0.0) == pytest.approx(1.0)
    with pytest.raises(ConfigError, match="near < far"):
        registry.load("reachers", "mink", hand=allegro, obj=cube, near=0.2, far=0.1)


# --- pre-grasps ---------------------------------------------------------------------------------
def test_pregrasps_clear_the_object_by_3cm_and_the_grasps_do_not(allegro, cube, plans) -> None:
    assert len(plans) == 10
    for plan in plans:
        for q, oMb, clear in (
            (plan.q_pre, plan.oMb_pre, True),
            (plan.q_grasp, plan.oMb_grasp, False),
        ):
            kin = HandKinematics(allegro)
            kin.update(q, oMb)
            points = kin.transform_points(allegro.samples.p_joint, allegro.samples.joint)
            assert bool(cube.sdf.query(points).min() >= 0.03) is clear
        assert plan.retreat == pytest.approx(round(plan.retreat / 0.005) * 0.005)


def test_nearest_plan_and_planner_skip_failedgrasp_plans(plans) -> None:
    wMo = np.eye(4)
    target = plans[3]
    wMb_now = wMo @ target.oMb_pre
    assert nearest_plan(plans, wMo, wMb_now) is target
    planner = ReachPlanner(plans, usable=lambda plan, wMo: True)
    assert planner.choose(wMo, wMb_now) is target
    planner.fail()
    assert planner.choose(wMo, wMb_now) is not target
    nobody = ReachPlanner(plans, usable=lambda plan, wMo: False)
    assert nobody.choose(wMo, wMb_now) is None


# --- transitions on constructed states ----------------------------------------------------------
class StandStill(Reacher):
    def step(self, q, wMb, wMo, targets, dt):
        return q.copy(), wMb.copy()


class Touching(ContactEstimator):
    """Reports one contact at 1 mm on each named finger's last link."""

    def __init__(self, hand, fingers):
        self.hand, self.fingers = hand, fingers

    def estimate(self, kinematics, wMo, stamp=0.0):
        from wholehand.contacts.base import ContactSet

        links = [self.hand.link_index(self.hand.config.fingers[f][-1]) for f in self.fingers]
        n = len(links)
        return ContactSet(
            p_world=np.zeros((n, 3)),
            n_world=np.tile([0.0, 0.0, 1.0], (n, 1)),
            link=np.asarray(links, dtype=np.intp),
            distance=np.full(n, 0.001),
            link_actuated=self.hand.link_actuated,
            link_fingertip=self.hand.link_fingertip,
        )


def context(hand, q, wMb, wMo, t=0.0) -> CycleContext:
    obs = Observation(q, np.zeros(hand.nv), wMb, t, wMo, t, JointHistory(hand.nq, 4))
    return CycleContext(t, 0.005, obs, hand, None, HandKinematics(hand), HandKinematics(hand))


def run_stage(stage: Stage, ctx: CycleContext) -> StageOutput:
    stage.start(ctx)
    return stage.step(ctx)


@pytest.mark.parametrize(("offset", "fires"), [(0.019, True), (0.021, False)])
def test_pregrasp_hands_over_below_2cm_mean_fingertip_error(allegro, plans, offset, fires) -> None:
    plan = plans[0]
    wMo = np.eye(4)
    wMb = wMo @ plan.oMb_pre
    wMb[:3, 3] += [0.0, offset, 0.0]  # every fingertip off its target by the same offset
    planner = ReachPlanner([plan], usable=lambda p, w: True)
    stage = ReachStage(allegro, StandStill(), planner, Touching(allegro, []), "pregrasp")
    out = run_stage(stage, context(allegro, plan.q_pre, wMb, wMo))
    assert (out.next == GRASP) is fires
    assert out.command is not None and out.command.base is not None


@pytest.mark.parametrize(
    ("fingers", "fires"),
    [
        (["thumb", "index", "middle"], True),
        (["thumb", "index"], False),
        (["index", "middle", "ring"], False),
    ],
)
def test_grasp_hands_over_on_thumb_and_two_fingers(allegro, plans, fingers, fires) -> None:
    plan = plans[0]
    planner = ReachPlanner([plan], usable=lambda p, w: True)
    planner.choose(np.eye(4), plan.oMb_grasp)
    stage = ReachStage(allegro, StandStill(), planner, Touching(allegro, fingers), "grasp")
    out = run_stage(stage, context(allegro, plan.q_grasp, plan.oMb_grasp, np.eye(4)))
    assert (out.next is not None) is fires


def _pinch(allegro, plan, own_fingers_only=False):
    """``plan`` as if made in the Allegro's pinch style (thumb and index), closing the joints
    the model derives (as the pipeline does), or with ``own_fingers_only`` only those of its
    two fingers."""
    from wholehand.models.grasp_styles import derived_close_torque, style_arrays
    from wholehand.models.motor_roles import motor_roles

    style = allegro.config.grasp_styles["pinch"]
    derived = derived_close_torque(allegro)
    if own_fingers_only:
        roles = motor_roles(allegro)
        derived = {j: t for j, t in derived.items() if roles[j].finger in ("thumb", "index")}
    closing = style_arrays(allegro, dataclasses.replace(style, close_torque=derived))[1]
    return dataclasses.replace(plan, style="pinch", fingers=("thumb", "index"), closing=closing)


@pytest.mark.parametrize(
    ("fingers", "fires"),
    [(["thumb", "index"], True), (["thumb", "middle", "ring"], False), (["index"], False)],
)
def test_a_pinch_hands_over_when_its_own_fingers_touch(allegro, plans, fingers, fires) -> None:
    plan = _pinch(allegro, plans[0])
    planner = ReachPlanner([plan], usable=lambda p, w: True)
    planner.choose(np.eye(4), plan.oMb_grasp)
    stage = ReachStage(allegro, StandStill(), planner, Touching(allegro, fingers), "grasp")
    out = run_stage(stage, context(allegro, plan.q_grasp, plan.oMb_grasp, np.eye(4)))
    assert (out.next is not None) is fires


def test_a_pinch_squeezes_its_own_closing_joints(allegro, plans) -> None:
    """At the grasp pose the servo aims SQUEEZE past the grasp on the closing joints of the
    plan's style: the pinch's (derived from the model), not the power style's."""
    from wholehand.models.grasp_styles import style_arrays
    from wholehand.reaching.stages import SQUEEZE

    power = plans[0]
    pinch = _pinch(allegro, power, own_fingers_only=True)
    power_closing = style_arrays(allegro, allegro.config.grasp_styles["power"])[1]
    assert np.any((pinch.closing != 0) != (power_closing != 0))  # the styles close differently
    for plan, closing in ((power, power_closing), (pinch, pinch.closing)):
        planner = ReachPlanner([plan], usable=lambda p, w: True)
        planner.choose(np.eye(4), plan.oMb_grasp)
        stage = ReachStage(
            allegro, StandStill(), planner, Touching(allegro, []), "grasp", closing=power_closing
        )
        servo = {}
        stage._servo = lambda obs, q, wMb, servo=servo: servo.setdefault("q", q)  # the aim
        run_stage(stage, context(allegro, plan.q_grasp, plan.oMb_grasp, np.eye(4)))
        expected = np.clip(
            plan.q_grasp + SQUEEZE * np.sign(closing), allegro.q_lower, allegro.q_upper
        )
        assert servo["q"] == pytest.approx(expected, abs=1e-9)


def test_the_planner_tells_a_failed_pinch_from_the_power_grasp_of_its_id(allegro, plans) -> None:
    power = plans[0]
    pinch = _pinch(allegro, power)
    planner = ReachPlanner([pinch, power], usable=lambda p, w: True)
    planner.choose(np.eye(4), pinch.oMb_grasp)
    chosen = planner.chosen
    planner.fail()
    assert planner.choose(np.eye(4), pinch.oMb_grasp) is not chosen  # the other, same id


def test_table_plans_take_every_styles_table_top_grasps(allegro) -> None:
    """The Duplo brick has table-top grasps in the pinch style only: from the table they are
    its plans, each with the pinch's fingers and closing joints; in the air, its power grasps."""
    from wholehand.models.object_catalogue import load_object
    from wholehand.reaching.pipeline import grasp_plans

    duplo = load_object("073-f_lego_duplo")
    table = grasp_plans(allegro, duplo, on_table=True)
    stored = load_grasps("allegro_right", duplo.name, "pinch", on_table=True)
    assert 0 < len(table) <= len(stored)
    pinch = _pinch(allegro, table[0])
    for plan in table:
        assert plan.style == "pinch" and plan.fingers == ("thumb", "index")
        assert plan.table_up is not None
        assert np.array_equal(plan.closing, pinch.closing)
    air = grasp_plans(allegro, duplo)
    assert air and {p.style for p in air} == {"power"} and all(p.closing is None for p in air)


def test_grasp_times_out_back_to_pregrasp_and_fails_the_plan(allegro, plans) -> None:
    plan = plans[0]
    planner = ReachPlanner([plan], usable=lambda p, w: True)
    planner.choose(np.eye(4), plan.oMb_grasp)
    stage = ReachStage(allegro, StandStill(), planner, Touching(allegro, ["thumb"]), "grasp")
    stage.start(context(allegro, plan.q_grasp, plan.oMb_grasp, np.eye(4), t=0.0))
    late = context(allegro, plan.q_grasp, plan.oMb_grasp, np.eye(4), t=3.01)
    out = stage.step(late)
    assert out.next == PREGRASP and "no grasp within 3.0 s" in out.reason
    assert (plan.style, plan.grasp_id) in planner.failed


def test_hold_stage_reports_a_loss_only_when_the_object_left_the_hand(allegro, cube, plans) -> None:
    plan = plans[0]

    class Regulation:
        hand = allegro

        def start(self, ctx):
            pass

        def tracking_lost(self, ctx):
            return None  # every pose here is within the hand's reach

        def step(self, ctx):
            return StageOutput(Command.torques(np.zeros(allegro.nv)), "ok")

    stage = HoldStage(Regulation(), GraspLossCheck(allegro, cube))  # type: ignore[arg-type]
    wMo = np.eye(4)
    held = run_stage(stage, context(allegro, plan.q_grasp, wMo @ plan.oMb_grasp, wMo))
    assert held.next is None and held.status == "ok"
    gone = np.eye(4)
    gone[:3, 3] = [0.0, 0.0, 0.3]
    lost = stage.step(context(allegro, plan.q_grasp, wMo @ plan.oMb_grasp, gone))
    assert lost.next == PREGRASP and lost.command is None


# --- MuJoCo: table and floating wrist -----------------------------------------------------------
def test_object_comes_to_rest_on_the_table_and_the_wrist_follows_commands(allegro, cube) -> None:
    table = Table(top=0.1)
    wMo = resting_pose(cube, UP, 0.0, (0.0, 0.0), table.top)
    wMo[2, 3] += 0.02  # dropped from 2 cm
    wMb = np.eye(4)
    wMb[:3, 3] = [0.3, 0.0, 0.5]
    backend = registry.load(
        "backends",
        "mujoco",
        hand=allegro,
        obj=cube,
        wMo_init=wMo,
        gravity=True,
        wMb=wMb,
        base="mocap",
        table=table,
    )
    moved = wMb.copy()
    moved[:3, 3] += [0.0, 0.05, -0.02]
    backend.apply(Command(np.zeros(allegro.nv), base=moved))
    backend.step(0.5)
    obs = backend.observe()
    np.testing.assert_allclose(obs.wMb, moved, atol=1e-9)
    rest = resting_pose(cube, UP, 0.0, (0.0, 0.0), table.top)
    assert abs(obs.wMo[2, 3] - rest[2, 3]) < 2e-3  # on the top face, within the penetration
    with pytest.raises(ConfigError, match="Command.base"):
        Command(np.zeros(allegro.nv), base=np.zeros((4, 4)))


def test_a_seeded_episode_grasps_loses_and_regrasps() -> None:
    from wholehand.cli.reach import format_summary
    from wholehand.reaching.episode import run_episode
    from wholehand.reaching.episode_spec import EpisodeSpec

    summary = run_episode(EpisodeSpec(seed=0), record=True)
    record = summary.pop("record")
    base = np.asarray(record.rows["p_base"])
    assert len(base) == summary["loop"]["cycles"]
    assert np.linalg.norm(base[-1] - base[0]) > 0.05  # the wrist moved, and the record shows it
    stages = [(t["source"], t["target"]) for t in summary["transitions"]]
    assert stages[:2] == [(PREGRASP, GRASP), (GRASP, "regulate")]
    assert (REGULATE, PREGRASP) in stages  # lost (to the snatch) ...
    assert stages[-1] == (GRASP, REGULATE)  # ... and regrasped
    assert summary["losses"] == 1 and summary["recovered"] == 1 and summary["complete"]
    assert summary["loop"]["n_errors"] == 0
    assert not any(summary["mujoco_warnings"].values())
    text = format_summary(summary)
    assert "duration [s]  perturbations  grasps  losses  recovered  complete" in text
    assert "person snatches the object" in text and "reach_grasp -> regulate" in text
    assert summary["reacher_faults"] == {} and "not taken as asked" not in text
    faulty = format_summary({**summary, "reacher_faults": {"relaxed": 3}})
    assert "reacher steps not taken as asked: {'relaxed': 3}" in faulty


def test_the_paper_balance_drops_the_cube_that_balancing_its_weight_holds() -> None:
    # Same seed, same grasp: without the weight in the QP the 252 g cube slips out once the
    # person lets go (the quasi-static allocation resists gravity only by the squeeze).
    from wholehand.reaching.episode import run_episode
    from wholehand.reaching.episode_spec import EpisodeSpec

    # The fingers' own weight is left to the grip here (the paper's tau = J^T f), as in the
    # paper; with it compensated the paper's balance holds this cube too (next test).
    paper = run_episode(
        EpisodeSpec(seed=0, balance_weight=False, gravity_compensation=False, duration=3.0)
    )
    lets_go = next(e["t"] for e in paper["events"] if e["what"] == "person lets go")
    lost = [t["t"] for t in paper["transitions"] if t["source"] == REGULATE]
    assert lost and lost[0] > lets_go
    balanced = run_episode(EpisodeSpec(seed=0, gravity_compensation=False, duration=3.0))
    assert not [t for t in balanced["transitions"] if t["source"] == REGULATE]


def test_compensating_the_fingers_weight_keeps_the_cube_the_paper_balance_dropped() -> None:
    from wholehand.reaching.episode import run_episode
    from wholehand.reaching.episode_spec import EpisodeSpec

    held = run_episode(EpisodeSpec(seed=0, balance_weight=False, duration=3.0))
    assert held["spec"]["gravity_compensation"]  # the episode's default
    assert held["grasps"] == 1 and held["losses"] == 0


def test_reach_study_rows_and_summary(tmp_path) -> None:
    from wholehand.studies import get_study, run_study

    result = run_study(get_study("reach"), "tiny", tmp_path, executor="serial", progress=False)
    (row,) = result.rows
    assert row["kind"] == "episode" and row["method"] == "qp+weight" and not row["error"]
    (group,) = result.summary["groups"]
    assert group["episodes"] == 1 and group["acquired"] == int(row["acquired"])
    assert group["recovered"] <= group["losses"] <= group["perturbations"]
    assert group["reacher_relaxed"] == row["reacher_relaxed"] >= 0 and row["reacher_held"] >= 0
    assert (tmp_path / "reach.png").stat().st_size > 0


def test_reach_table_study_runs_from_the_table_on_the_objects_with_table_top_grasps(
    tmp_path,
) -> None:
    from toy_hand import write_toy_hand

    from wholehand.errors import ConfigError
    from wholehand.grasps.store import grasp_file
    from wholehand.models.object_catalogue import PAPER_OBJECTS
    from wholehand.studies import get_study, run_study

    study = get_study("reach-table")
    jobs = study.jobs("quick", 0, "allegro_right")
    styles = ("power", "precision", "pinch")
    with_grasps = [
        o
        for o in PAPER_OBJECTS
        if any(grasp_file("allegro_right", o, s, on_table=True).is_file() for s in styles)
    ]
    assert sorted({j.spec.object for j in jobs}) == sorted(with_grasps)
    assert "073-f_lego_duplo" in with_grasps  # its table-top grasps are pinches only
    assert {j.labels["start"] for j in jobs} == {"table"}
    with pytest.raises(ConfigError, match="no table-top grasps.*--on-table --method optimize"):
        study.jobs("quick", 0, str(write_toy_hand(tmp_path / "toy")))
    result = run_study(study, "tiny", tmp_path / "out", executor="serial", progress=False)
    (row,) = result.rows
    assert row["start"] == "table" and row["object"] == "077_rubiks_cube" and not row["error"]
    assert row["acquired"]  # the cube is picked off the table with a synthesised grasp


# --- three facts about mink's collision limit, and what the reacher does about each -------------
def test_mesh_distance_is_to_the_hull_so_the_object_collides_as_its_parts(allegro) -> None:
    # A probe at the centre of a cup's cavity is inside the cup's convex hull (MuJoCo's distance
    # to a mesh geom is to its hull) but clear of every convex part of its decomposition.
    import mujoco
    from wholehand_plugins.mink_reacher import build_reach_model

    from wholehand.models.convex import convex_decomposition
    from wholehand.models.object_catalogue import load_object

    cup = load_object("065-f_cups")
    spec = mujoco.MjSpec()
    hull = cup.mesh.convex_hull
    parts = convex_decomposition(cup.mesh, name=cup.name).parts()
    for name, (v, f) in [
        ("hull", (hull.vertices, hull.faces)),
        *[(f"part{i}", p) for i, p in enumerate(parts)],
    ]:
        mesh = spec.add_mesh(name=name)
        mesh.uservert = np.asarray(v, dtype=np.float32).ravel().tolist()
        mesh.userface = np.asarray(f, dtype=np.int32).ravel().tolist()
        spec.worldbody.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=name)
    lo, hi = cup.mesh.bounds
    probe = spec.worldbody.add_body(name="probe", mocap=True, pos=(0.5 * (lo + hi)).tolist())
    probe.add_geom(name="probe", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.005, 0, 0])
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    fromto = np.zeros(6)

    def distance(geom: str) -> float:
        return mujoco.mj_geomDistance(
            model, data, model.geom(geom).id, model.geom("probe").id, 0.2, fromto
        )

    assert distance("hull") < 0.0
    assert min(distance(f"part{i}") for i in range(len(parts))) > 0.005
    _, _, object_geoms, _ = build_reach_model(allegro, cup, None)
    assert len(object_geoms) == len(parts) > 1


def test_mink_drops_pairs_with_a_world_geom_so_table_and_object_are_mocap_bodies(
    allegro, cube
) -> None:
    # mink's parent-child filter drops every pair of a body hanging from the world (a floating
    # hand's root, an arm's first link) with a geom of the world body; a mocap body keeps them.
    import mink
    import mujoco
    from wholehand_plugins.mink_reacher import build_reach_model

    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_BOX, size=[1, 1, 0.01])
    hand = spec.worldbody.add_body(name="hand", pos=[0, 0, 0.5])
    hand.add_freejoint()
    hand.add_geom(name="palm", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.05, 0, 0])
    on_mocap = spec.worldbody.add_body(name="stand", mocap=True)
    on_mocap.add_geom(name="top", type=mujoco.mjtGeom.mjGEOM_BOX, size=[1, 1, 0.01])
    model = spec.compile()
    assert not mink.CollisionAvoidanceLimit(model, [(["palm"], ["floor"])]).geom_id_pairs
    assert mink.CollisionAvoidanceLimit(model, [(["palm"], ["top"])]).geom_id_pairs

    model, hand_geoms, object_geoms, _ = build_reach_model(allegro, cube, Table())
    for body in ("table", "object"):
        assert model.body_mocapid[model.body(body).id] >= 0
    palm = [g for g in hand_geoms if g.startswith(allegro.palm_link)]
    assert mink.CollisionAvoidanceLimit(model, [(palm, ["table"])]).geom_id_pairs
    assert mink.CollisionAvoidanceLimit(model, [(palm, object_geoms)]).geom_id_pairs


def test_a_target_behind_the_object_does_not_pull_the_hand_through_it(allegro, cube) -> None:
    # Large steps could jump past a limit that only acts within its detection distance; the
    # reacher's speed cap keeps steps (1.5 mm at 200 Hz) far below it (4 cm), so the hand
    # stops at the object instead of passing through to a target on its far side.
    reacher = registry.load("reachers", "mink", hand=allegro, obj=cube, table=None)
    wMo = np.eye(4)
    q = allegro.neutral()
    wMb = np.eye(4)
    wMb[:3, 3] = [0.0, 0.0, 0.2]
    through = wMb.copy()
    through[2, 3] = -0.2
    targets = tip_and_palm_poses(allegro, q, through)
    kin = HandKinematics(allegro)
    closest = np.inf
    for _ in range(400):
        q, wMb = reacher.step(q, wMb, wMo, ReachTargets(targets, q, allegro.palm_link), 0.005)
        kin.update(q, wMb)
        points = kin.transform_points(allegro.samples.p_joint, allegro.samples.joint)
        closest = min(closest, float(cube.sdf.query(points).min()))
    assert -0.001 < closest < 0.01, closest  # came to the object, never more than 1 mm into it


def test_a_floating_wrist_holds_the_hand_up_and_yields_when_pressed_on_an_object(
    allegro,
) -> None:
    # The floating base is welded softly to a moved target: it carries the hand's weight
    # (sub-millimetre sag) and follows the target. Driven 6 cm into a box lying on the table it
    # yields, where a kinematic (mocap) wrist crushes the box into the table and MuJoCo
    # diverges (the cause of the diverged reach episodes), retried steps included.
    from wholehand.models.objects import ObjectModel

    table = Table(top=0.0)
    box = ObjectModel.box((0.06, 0.06, 0.06), mass=0.2)
    wMo = resting_pose(box, UP, 0.0, (0.0, 0.0), table.top)
    wMb = np.eye(4)
    wMb[:3, :3] = [[0, 0, -1], [0, 1, 0], [1, 0, 0]]  # palm (x) facing down
    wMb[:3, 3] = [0.0, 0.0, 0.2]
    outcome = {}
    for base in ("floating", "mocap"):
        backend = registry.load(
            "backends",
            "mujoco",
            hand=allegro,
            obj=box,
            wMo_init=wMo,
            gravity=True,
            wMb=wMb,
            base=base,
            table=table,
        )
        if base == "floating":
            backend.apply(Command(np.zeros(allegro.nv)))
            backend.step(0.3)
            assert abs(backend.observe().wMb[2, 3] - 0.2) < 1e-3
            moved = wMb.copy()
            moved[0, 3] += 0.05
            backend.apply(Command(np.zeros(allegro.nv), base=moved))
            backend.step(0.3)
            np.testing.assert_allclose(backend.observe().wMb[:3, 3], moved[:3, 3], atol=1e-3)
        pressed = wMb.copy()
        pressed[2, 3] = 0.0  # the palm 6 cm into the box, at the table top
        for _ in range(100):
            backend.apply(Command(np.zeros(allegro.nv), base=pressed))
            backend.step(0.005)
        counts = backend.warnings()
        outcome[base] = (backend.observe(), counts["bad_qacc"] + counts["step_retries_failed"])
    obs, diverged = outcome["floating"]
    assert diverged == 0
    assert obs.wMo[2, 3] > 0.0  # the box is still above the table top (penetrating < 3 cm)
    assert obs.wMb[2, 3] > pressed[2, 3] + 0.04  # the wrist gave way
    obs, diverged = outcome["mocap"]
    assert diverged > 0  # not even a step retried without hand-hand friction can resolve it


@pytest.mark.parametrize("self_collision", [False, True])
def test_self_collision_keeps_two_fingers_apart(allegro, cube, self_collision) -> None:
    # The index and middle fingertips are both sent to the middle tip's place: without the
    # limit they run into each other; with it they stop SELF_CLEARANCE apart.
    import mujoco
    from wholehand_plugins.mink_reacher import SELF_CLEARANCE

    reacher = registry.load(
        "reachers", "mink", hand=allegro, obj=cube, self_collision=self_collision
    )
    q = allegro.neutral()
    wMb = np.eye(4)
    wMb[:3, 3] = [0.0, 0.0, 0.5]
    targets = tip_and_palm_poses(allegro, q, wMb)
    targets["link_3.0_tip"] = targets["link_7.0_tip"].copy()
    far = np.eye(4)
    far[:3, 3] = [1.0, 1.0, 1.0]
    for _ in range(300):
        q, wMb = reacher.step(q, wMb, far, ReachTargets(targets, q, allegro.palm_link), 0.005)
    model, data = reacher.model, reacher.configuration.data
    fromto = np.zeros(6)
    index = [
        g
        for g in range(model.ngeom)
        if model.body(model.geom_bodyid[g]).name in ("link_3.0", "link_3.0_tip")
    ]
    middle = [
        g
        for g in range(model.ngeom)
        if model.body(model.geom_bodyid[g]).name in ("link_7.0", "link_7.0_tip")
    ]
    gap = min(
        mujoco.mj_geomDistance(model, data, a, b, 0.05, fromto) for a in index for b in middle
    )
    if self_collision:  # the fingers never touch; the damper stops within 1 mm of the clearance
        assert 0.5 * SELF_CLEARANCE < gap < 2.0 * SELF_CLEARANCE
    else:
        assert gap < -0.01


def test_a_floating_wrist_never_starts_inside_the_object(allegro) -> None:
    # The start used to be the pre-grasp lifted 10 cm and moved at random: 13 of these 40
    # draws put the hand into the mustard bottle (the palm 5 cm deep in one), and MuJoCo
    # ejected the thumb at 200 rad/s in the first steps. Ground truth here: the SDF distance of
    # every hand sample.
    from wholehand.models.object_catalogue import load_object
    from wholehand.reaching.episode import (
        START_CLEARANCE,
        START_LIFT,
        START_SPREAD,
        episode_table,
        floating_start,
    )
    from wholehand.reaching.pipeline import grasp_plans
    from wholehand.reaching.pregrasp import hand_clearance

    obj = load_object("006_mustard_bottle")
    plans, table = grasp_plans(allegro, obj), episode_table(allegro)
    wMo = np.eye(4)
    wMo[:3, 3] = [*table.centre, table.top + 0.25]
    naive_inside = 0
    for seed in range(40):
        plan = plans[seed % len(plans)]
        naive = wMo @ plan.oMb_pre
        draw = np.random.default_rng(seed).normal(size=2)
        naive[:3, 3] += np.array([0.0, 0.0, START_LIFT]) + START_SPREAD * np.r_[draw, 0.0]
        oMw = np.linalg.inv(wMo)
        naive_inside += hand_clearance(allegro, obj, plan.q_pre, oMw @ naive) < 0.0
        wMb = floating_start(allegro, obj, plan, wMo, table, np.random.default_rng(seed))
        assert hand_clearance(allegro, obj, plan.q_pre, oMw @ wMb) >= START_CLEARANCE
        assert lowest_point(allegro, plan.q_pre, wMb) >= table.top
    assert naive_inside >= 1  # the redraw was needed


def test_a_plan_check_with_the_callers_kinematics_gives_the_same_answer(allegro) -> None:
    """The stages check every plan in a control cycle through one kinematics object (building
    one per check cost 9 ms per choice); the answers are those of fresh ones, down to the
    lowest point's bits."""
    from wholehand.models.object_catalogue import load_object
    from wholehand.reaching.episode import episode_table
    from wholehand.reaching.pipeline import grasp_plans
    from wholehand.reaching.pregrasp import usable_on_table

    obj = load_object("077_rubiks_cube")
    plans, table = grasp_plans(allegro, obj), episode_table(allegro)
    shared = HandKinematics(allegro)
    answers = []
    for height in (0.02, 0.06, 0.25):  # low poses put some plans below the table top
        wMo = np.eye(4)
        wMo[:3, 3] = [*table.centre, table.top + height]
        for plan in plans:
            fresh = usable_on_table(allegro, plan, wMo, table, 0.01)
            assert usable_on_table(allegro, plan, wMo, table, 0.01, shared) == fresh
            answers.append(fresh)
            low = lowest_point(allegro, plan.q_pre, wMo @ plan.oMb_pre)
            assert lowest_point(allegro, plan.q_pre, wMo @ plan.oMb_pre, shared) == low
    assert any(answers) and not all(answers)


def test_pushes_and_twists_spare_an_object_the_hand_has_dropped() -> None:
    # A twist of 0.1 N*m on a dropped Lego brick (a few 1e-5 kg*m^2) spun it at 1000 rad/s.
    from types import SimpleNamespace

    from wholehand.reaching.episode_spec import EpisodeSpec
    from wholehand.reaching.person import GAP, Person

    class Pushes:
        def __init__(self) -> None:
            self.wrenches: list[tuple[float, float]] = []

        def set_object_spring(self, *args: object) -> None:
            pass

        def apply_object_wrench(self, force: np.ndarray, torque: np.ndarray) -> None:
            self.wrenches.append((float(np.linalg.norm(force)), float(np.linalg.norm(torque))))

    spec = EpisodeSpec()
    for held in (True, False):
        backend = Pushes()
        rng = np.random.default_rng(0)
        person = Person(spec, backend, np.eye(4), rng, (0.1, 1e-5), "palm", 0.03)
        person.state, person.since = "released", 0.0
        stage = REGULATE if held else PREGRASP
        t = 0.0
        while person.state != "twisted" and t < 10.0:  # up to the snatch
            t += 0.05
            person.on_cycle(SimpleNamespace(t=t, stage=stage))  # type: ignore[arg-type]
        assert t < 2 * (GAP + spec.pulse) + 0.1
        notes = [e.what for e in person.events]
        if held:
            # One weight of the 0.1 kg object, and that force 3 cm from its centre.
            assert notes == ["push 0.98 N for 0.3 s", "twist 0.029 N*m for 0.3 s"]
            push, twist = (pytest.approx(0.981), 0.0), (0.0, pytest.approx(0.02943))
            assert backend.wrenches == [push, (0.0, 0.0), twist, (0.0, 0.0)]
        else:
            assert notes == [
                "no push: the hand holds no object",
                "no twist: the hand holds no object",
            ]
            assert backend.wrenches == []


def test_a_dropped_object_is_carried_back_at_a_persons_pace() -> None:
    # An object flung off the table lay 13 m below it; a grip stretched that far yanked it at
    # 300 m/s. The grip's target now starts at the object and moves at PICKUP_SPEED.
    from types import SimpleNamespace

    from wholehand.reaching.episode_spec import EpisodeSpec
    from wholehand.reaching.person import GAP, PICKUP_SPEED, Person

    class Grips:
        def __init__(self) -> None:
            self.targets: list[np.ndarray] = []

        def set_object_spring(self, wMo: np.ndarray | None, *gains: object) -> None:
            if wMo is not None:
                self.targets.append(wMo[:3, 3].copy())

        def apply_object_wrench(self, *wrench: object) -> None:
            pass

    backend = Grips()
    held_at = np.eye(4)
    held_at[:3, 3] = [0.0, 0.0, 1.0]
    rng = np.random.default_rng(0)
    person = Person(EpisodeSpec(), backend, held_at, rng, (0.1, 1e-5), "p", 0.03)
    person.state, person.since = "twisted", 0.0
    fallen = np.eye(4)
    fallen[:3, 3] = [2.0, 2.0, -5.0]
    dt, t = 0.005, GAP
    for _ in range(400):
        cycle = SimpleNamespace(t=t, stage=PREGRASP, truth=SimpleNamespace(wMo=fallen))
        person.on_cycle(cycle)  # type: ignore[arg-type]
        t += dt
    assert [e.what for e in person.events] == [
        "person picks the dropped object up and holds it out"
    ]
    targets = np.asarray(backend.targets)
    np.testing.assert_allclose(targets[0], fallen[:3, 3])
    steps = np.linalg.norm(np.diff(targets, axis=0), axis=1)
    assert steps.max() <= PICKUP_SPEED * dt + 1e-9
    assert np.linalg.norm(targets[-1] - fallen[:3, 3]) == pytest.approx(PICKUP_SPEED * 399 * dt)


def test_the_self_collision_method_reaches_and_grasps_with_the_fingers_kept_apart() -> None:
    from wholehand.reaching.episode import run_episode
    from wholehand.reaching.episode_spec import EpisodeSpec
    from wholehand.studies.reach import METHODS

    assert METHODS["qp+weight+self"].self_collision and METHODS["qp+weight+self"].balance_weight
    assert not METHODS["qp+weight"].self_collision
    summary = run_episode(EpisodeSpec(seed=0, self_collision=True, duration=2.5))
    assert summary["spec"]["self_collision"] and summary["grasps"] == 1


def test_reach_cli_passes_the_episode_options(capsys) -> None:
    import json

    from wholehand.cli.main import main

    args = ["reach", "--duration", "1.0", "--self-collision", "--push", "0.5", "--json"]
    assert main(args) == 0
    spec = json.loads(capsys.readouterr().out)["spec"]
    assert spec["self_collision"] and spec["push"] == 0.5 and spec["twist"] == 1.0
    assert spec["balance_weight"] and spec["gravity_compensation"]


def test_reach_takes_a_users_hand_folder_whose_name_differs_from_its_folder(
    tmp_path, capsys
) -> None:
    """Every command resolves ``--hand`` one way: a user's folder is found by its path whatever
    its hand.toml calls the hand, and its grasps are read from the folder's grasps/."""
    import json
    import shutil

    from wholehand.cli.main import main
    from wholehand.grasps.store import grasp_file
    from wholehand.models.hand_folders import shipped_hands_dir

    folder = tmp_path / "lab_hand"
    shutil.copytree(shipped_hands_dir() / "allegro_right", folder)
    toml = folder / "hand.toml"
    toml.write_text(toml.read_text().replace('name = "allegro_right"', 'name = "our_lab_hand"'))
    args = ["reach", "--hand", str(folder), "--duration", "0.4", "--json"]
    assert main(args) == 2  # no grasps yet: the fix names the folder, not the hand's name
    err = capsys.readouterr().err
    assert f"grasps generate --hand {folder} --object 077_rubiks_cube" in err
    stored = grasp_file("allegro_right", "077_rubiks_cube")
    (folder / "grasps").mkdir()
    shutil.copy(stored, folder / "grasps" / stored.name)
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["spec"]["hand"] == str(folder) and report["transitions"]  # it reached


def test_an_episode_from_the_table_regrasps_the_object_where_it_lies(allegro) -> None:
    """start="table": the box rests on the table, is slid while the hand reaches, grasped from
    above, pushed and twisted, pulled out from under the hand along the table and put down;
    the hand regrasps it there. Neither the hand nor the box goes into the table."""
    import pinocchio as pin

    from wholehand.models.object_catalogue import load_object
    from wholehand.reaching.episode import episode_table, run_episode
    from wholehand.reaching.episode_spec import EpisodeSpec

    spec = EpisodeSpec(seed=0, object="003_cracker_box", start="table")
    summary = run_episode(spec, record=True)
    rows = summary.pop("record").rows
    events = [e["what"] for e in summary["events"]]
    assert (
        events[0].startswith("person moves")
        and events[1] == "person leaves the object on the table"
    )
    assert any(
        e.startswith("person snatches the object") and "along the table" in e for e in events
    )
    assert events[-1] == "person leaves the object on the table"
    assert summary["losses"] == 1 and summary["recovered"] == 1 and summary["complete"]
    assert summary["loop"]["n_errors"] == 0 and not any(summary["mujoco_warnings"].values())
    top = episode_table(allegro).top
    box = np.asarray(load_object("003_cracker_box").mesh.vertices)
    kin = HandKinematics(allegro)
    for i in range(0, len(rows["q"]), 10):
        wMb = np.eye(4)
        wMb[:3, :3], wMb[:3, 3] = pin.exp3(rows["r_base"][i]), rows["p_base"][i]
        kin.update(rows["q"][i], wMb)
        hand = kin.transform_points(allegro.samples.p_joint, allegro.samples.joint)
        assert hand[:, 2].min() > top  # the grasps come from above
        R = pin.exp3(rows["r_object"][i])
        lowest = (box @ R.T + rows["p_object"][i])[:, 2].min()
        assert top - 1e-3 < lowest < top + 0.01  # on the table throughout, within 1 mm


def test_a_table_top_grasp_without_its_face_is_named(monkeypatch) -> None:
    import dataclasses

    import wholehand.reaching.episode as episode
    import wholehand.reaching.pipeline as pipeline

    real = pipeline.load_grasps

    def faceless(*args: object, **kwargs: object) -> list:
        return [dataclasses.replace(g, extra={}) for g in real(*args, **kwargs)]

    monkeypatch.setattr(pipeline, "load_grasps", faceless)
    spec = episode.EpisodeSpec(object="003_cracker_box", start="table")
    with pytest.raises(ConfigError, match="has no table_up.*--on-table"):
        episode.run_episode(spec)
    with pytest.raises(ConfigError, match="start must be one of"):
        episode.run_episode(episode.EpisodeSpec(start="floor"))
    with pytest.raises(ConfigError, match="push must be >= 0"):
        episode.run_episode(episode.EpisodeSpec(push=-1.0))


def test_hold_stage_keeps_regulating_through_lost_tracking_until_the_ramp_ends(allegro, cube):
    from wholehand.loop.tracking import TRACKING_HOLD, TRACKING_RAMP

    class Regulation:
        hand = allegro
        lost_for: float | None = None

        def start(self, ctx):
            pass

        def tracking_lost(self, ctx):
            return self.lost_for

        def step(self, ctx):
            return StageOutput(None, "tracking_lost")

    regulation = Regulation()
    stage = HoldStage(regulation, GraspLossCheck(allegro, cube))  # type: ignore[arg-type]
    far = np.eye(4)
    far[:3, 3] = [10.0, 0.0, 0.0]  # the hull check alone would call this a loss
    regulation.lost_for = TRACKING_HOLD + TRACKING_RAMP - 0.01
    out = run_stage(stage, context(allegro, allegro.neutral(), np.eye(4), far))
    assert out.next is None and out.status == "tracking_lost"
    regulation.lost_for = TRACKING_HOLD + TRACKING_RAMP
    out = stage.step(context(allegro, allegro.neutral(), np.eye(4), far))
    assert out.next == PREGRASP and "out of the hand's reach for 0.70 s" in out.reason


def _person():
    from wholehand.reaching.episode_spec import EpisodeSpec
    from wholehand.reaching.person import Person

    return Person(
        EpisodeSpec(), None, np.eye(4), np.random.default_rng(0), (0.25, 1e-4), "palm", 0.03
    )


def test_an_episode_with_a_perturbation_left_out_is_not_complete() -> None:
    from wholehand.reaching.person import Event

    person = _person()
    person.done = True
    person.events = [Event(2.5, "push 2.47 N for 0.3 s"), Event(3.8, "twist 0.094 N*m for 0.3 s")]
    assert person.complete and person.skipped == []
    person.events[1] = Event(3.8, "no twist: the hand holds no object")
    assert not person.complete and person.skipped == ["no twist: the hand holds no object"]


def test_the_last_hold_is_timed_from_the_release_not_from_the_grasp() -> None:
    """Grasped at 6.0 s, let go at 6.5 s, hold_after 1 s: complete at 7.5 s, not 7.0 s."""
    from types import SimpleNamespace

    person = _person()
    person.state, person.since = "regrasped", 6.5
    assert person._wait_for_the_end(SimpleNamespace(t=7.0), True, 1.0) is None
    assert not person.done
    assert person._wait_for_the_end(SimpleNamespace(t=7.5), True, 1.5) == "episode complete"
    assert person.done
    dropped = _person()
    dropped.state, dropped.since = "regrasped", 6.5
    assert dropped._wait_for_the_end(SimpleNamespace(t=9.0), False, 0.0) is None


def test_what_a_stage_says_without_switching_is_noted_once_per_change() -> None:
    """A replan's reason is kept for the timeline; the same reason in the next cycles is not
    repeated, a new one is."""
    from wholehand.loop.control_loop import ControlLoop
    from wholehand.loop.report import LoopReport

    loop = object.__new__(ControlLoop)
    loop.report, loop.active = LoopReport(), "reach_pregrasp"
    for t in (1.0, 1.005, 1.01):
        loop._note(t, "no_plan", "no usable grasp plan at the object's pose (10 stored)")
    loop._note(4.0, "replan", "pre-grasp not reached within 3 s: grasp 4; next: grasp 7")
    loop._note(4.005, "no_plan", "no usable grasp plan at the object's pose (10 stored)")
    notes = [(n.t, n.status) for n in loop.report.notes]
    assert notes == [(1.0, "no_plan"), (4.0, "replan"), (4.005, "no_plan")]
    assert loop.report.as_dict()["notes"][1]["reason"].endswith("next: grasp 7")


def test_the_robot_conditions_study_adds_each_condition_on_the_same_seeds(monkeypatch) -> None:
    """Each object and seed runs in process, with the tracker, with the deadline, with both,
    with the tracker and the controller's pose prediction, and with those and a person who lets
    go on touch; the episode gets exactly that condition."""
    from wholehand.reaching import episode as episode_module
    from wholehand.studies import get_study
    from wholehand.studies.reach import PREDICTION, ROBOT_DEADLINE, TRACKER, episode_row

    jobs = get_study("robot-conditions").jobs("quick", seed=3)
    by_seed: dict[int, list[str]] = {}
    for job in jobs:
        by_seed.setdefault(job.spec.seed, []).append(job.labels["method"])
    assert len(by_seed) == 5
    conditions = ["in-process", "tracker", "deadline", "tracker+deadline", "tracker+predict"]
    conditions += ["tracker+predict+touch", "tracker+predict+servo"]
    assert all(m == conditions for m in by_seed.values())
    seen = []

    def fake_episode(spec, **kwargs):
        seen.append(spec)
        return {"complete": True, "grasps": 1, "time_to_grasp_s": 1.0, "losses": 1,
                "loss_causes": ["gravity"], "recovered": 1, "perturbations": 4,
                "duration_s": 7.0, "loop": {"cycles": 100, "n_errors": 0},
                "mujoco_warnings": {}, "reacher_faults": {"relaxed": 2}}  # fmt: skip

    monkeypatch.setattr(episode_module, "run_episode", fake_episode)
    rows = [episode_row(job) for job in jobs[:7]]
    assert all(r["reacher_relaxed"] == 2 and r["reacher_held"] == 0 for r in rows)
    plain, tracked, hurried, both, predicted, touched, servoed = seen
    assert all(s.person_sees == "stage" for s in seen[:5]) and touched.person_sees == "contacts"
    assert all(s.hand_servo == "step" for s in seen[:6]) and servoed.hand_servo == "command"
    assert (touched.tracker_rate, touched.tracker_predict) == (TRACKER[0], PREDICTION)
    assert (plain.tracker_rate, plain.qp_deadline) == (0.0, 0.0)
    assert all(s.tracker_predict == 0.0 for s in seen[:4])
    assert (predicted.tracker_rate, predicted.tracker_latency) == TRACKER
    assert predicted.tracker_predict == PREDICTION and predicted.qp_deadline == 0.0
    assert (tracked.tracker_rate, tracked.tracker_latency) == TRACKER
    assert hurried.qp_deadline == ROBOT_DEADLINE and hurried.tracker_rate == 0.0
    assert (both.tracker_rate, both.qp_deadline) == (TRACKER[0], ROBOT_DEADLINE)
    assert all(s.balance_weight for s in seen) and rows[0]["losses_release"] == 1


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("tracker_rate", -30.0),
        ("tracker_latency", float("nan")),
        ("tracker_predict", -0.1),
        ("qp_deadline", -1.0),
    ],
)
def test_bad_robot_conditions_of_an_episode_are_named(field, value) -> None:
    from wholehand.reaching.episode import _check_spec
    from wholehand.reaching.episode_spec import EpisodeSpec

    with pytest.raises(ConfigError, match=f"EpisodeSpec: {field} must be >= 0"):
        _check_spec(EpisodeSpec(**{field: value}))


def test_an_unknown_way_for_the_person_to_judge_a_grasp_is_named() -> None:
    from wholehand.reaching.episode import _check_spec
    from wholehand.reaching.episode_spec import EpisodeSpec

    with pytest.raises(ConfigError, match="person_sees must be one of .*'contacts'.*'touch'"):
        _check_spec(EpisodeSpec(person_sees="touch"))


def test_an_unknown_hand_servo_of_an_episode_is_named() -> None:
    from wholehand.reaching.episode import _check_spec
    from wholehand.reaching.episode_spec import EpisodeSpec

    with pytest.raises(ConfigError, match="EpisodeSpec: hand_servo must be one of"):
        _check_spec(EpisodeSpec(hand_servo="drives"))
