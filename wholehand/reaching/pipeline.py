"""The stage machine of the autonomous pipeline, built once for simulation and for a robot.

:func:`pipeline_stages` gives ``reach_pregrasp``, ``reach_grasp`` and ``regulate``
(:mod:`wholehand.reaching.stages`), and, for a robot's arm with a workspace, ``home``
(:mod:`wholehand.reaching.home`). ``wholehand reach`` (:mod:`wholehand.reaching.episode`) and
``wholehand control`` on an arm-hand (:mod:`wholehand.robot.controller`) both run it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from wholehand.contacts.base import ContactEstimator
from wholehand.errors import ConfigError
from wholehand.grasps.store import load_grasps
from wholehand.loop.grasp_loss import GraspLossCheck
from wholehand.loop.regulation import ForceRegulation
from wholehand.loop.stage import Stage
from wholehand.models.grasp_styles import style_arrays
from wholehand.models.hand import HandModel
from wholehand.models.objects import ObjectModel
from wholehand.reaching.base import Reacher
from wholehand.reaching.home import HomeStage
from wholehand.reaching.pregrasp import GraspPlan, plan_pregrasp
from wholehand.reaching.stages import (
    GRASP,
    HOME,
    PREGRASP,
    REGULATE,
    HoldStage,
    ReachPlanner,
    ReachStage,
)
from wholehand.reaching.workspace import Workspace

FloatArray = npt.NDArray[np.float64]


def grasp_hand_of(hand: HandModel) -> HandModel:
    """The hand whose grasps an assembly uses (the hand itself when it is not an assembly)."""
    from wholehand.models.hand import load_hand

    return load_hand(hand.config.hand_toml) if hand.config.hand_toml else hand


def grasp_plans(hand: HandModel, obj: ObjectModel, on_table: bool = False) -> list[GraspPlan]:
    """The plans of the hand's stored power grasps; with ``on_table``, of its table-top grasps
    of every grasp style (power first), so that e.g. a pinch picks an object too small for a
    power grasp.

    Raises:
        ConfigError: no stored grasp has a pre-grasp; no grasp file (the power style's
            message, naming the command that makes one).
    """
    q_open = style_arrays(hand, hand.config.grasp_styles["power"])[0]
    styles = list(hand.config.grasp_styles) if on_table else ["power"]
    styles = ["power", *(s for s in styles if s != "power")]
    found: list[GraspPlan] = []
    missing: list[ConfigError] = []
    for name in styles:
        try:
            grasps = load_grasps(hand.config.reference, obj.name, name, on_table=on_table)
        except ConfigError as err:
            missing.append(err)
            continue
        style = None if name == "power" else hand.config.grasp_styles[name]
        plans = [plan_pregrasp(hand, obj, g, q_open, style=style) for g in grasps]
        found += [p for p in plans if p is not None]
    if len(missing) == len(styles):  # no grasp file at all: the power style's message
        raise missing[0]
    if not found:
        raise ConfigError(f"no stored grasp of {obj.name!r} for {hand.name!r} has a pre-grasp")
    return found


def home_configuration(
    hand: HandModel, grasp_hand: HandModel, arm_home: tuple[float, ...] | None = None
) -> FloatArray:
    """(n_q,) an assembly's home: the arm at ``arm_home`` (its ``[assembly] home`` if None), in
    the order of ``hand.config.arm_joints``, and the fingers at the power style's pre-shape."""
    model = hand.model
    q = np.zeros(hand.nq)
    home = hand.config.arm_home if arm_home is None else arm_home
    for name, value in zip(hand.config.arm_joints, home, strict=True):
        q[model.joints[model.getJointId(name)].idx_q] = value
    q_open = style_arrays(grasp_hand, grasp_hand.config.grasp_styles["power"])[0]
    for name in grasp_hand.joint_names:
        i = grasp_hand.model.joints[grasp_hand.model.getJointId(name)].idx_q
        q[model.joints[model.getJointId(name)].idx_q] = q_open[i]
    return q


@dataclass(frozen=True)
class RobotRules:
    """What a robot adds to the stage machine (:mod:`wholehand.reaching.stages`)."""

    workspace: Workspace
    pose_timeout: float
    """A reaching stage holds the arm and fingers once the pose is this old [s]."""
    q_home: FloatArray
    """(n_q,) the home configuration (:func:`home_configuration`)."""


def pipeline_stages(
    hand: HandModel,
    grasp_hand: HandModel,
    obj: ObjectModel,
    planner: ReachPlanner,
    estimator: ContactEstimator,
    reacher: Reacher,
    regulation: ForceRegulation,
    gravity_compensation: bool,
    robot: RobotRules | None = None,
) -> tuple[dict[str, Stage], tuple[ReachStage, ReachStage]]:
    """The stages by name, and the two reaching stages (for their timings).

    Args:
        hand: the hand or arm-hand assembly the loop drives.
        grasp_hand: the hand whose stored grasps the plans are (``hand`` itself, or an
            assembly's hand).
        planner: the plans and the rule of which are usable.
        gravity_compensation: the finger servo adds the links' gravity torques.
        robot: a robot's workspace, pose timeout and home (None: simulation, no ``home``).
    """
    closing = style_arrays(grasp_hand, grasp_hand.config.grasp_styles["power"])[1]
    workspace = None if robot is None else robot.workspace
    pose_timeout = None if robot is None else robot.pose_timeout
    pregrasp, grasp = (
        ReachStage(
            hand,
            reacher,
            planner,
            estimator,
            kind,
            closing=closing if kind == "grasp" else None,
            grasp_hand=grasp_hand,
            gravity_compensation=gravity_compensation,
            workspace=workspace,
            pose_timeout=pose_timeout,
        )
        for kind in ("pregrasp", "grasp")
    )
    stages: dict[str, Stage] = {
        PREGRASP: pregrasp,
        GRASP: grasp,
        REGULATE: HoldStage(regulation, GraspLossCheck(hand, obj)),
    }
    if robot is not None:
        stages[HOME] = HomeStage(
            hand, robot.q_home, robot.workspace, robot.pose_timeout, gravity_compensation
        )
    return stages, (pregrasp, grasp)


def always_usable(plan: GraspPlan, wMo: FloatArray) -> bool:
    """Every plan is usable (no table)."""
    return True
