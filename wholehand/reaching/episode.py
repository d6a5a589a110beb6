"""A seeded reach-grasp-hold-regrasp episode in MuJoCo with gravity (``wholehand reach``).

The hand hangs on a floating wrist (a mocap base) above a table. A person (a stiff
spring-damper on the object) holds the object out in the air:

1. while the hand reaches, the person moves the object by ``displace`` in a seeded horizontal
   direction and turns it about the vertical (the hand must follow);
2. once the hand has held it for ``release_after``, the person lets go (gravity on);
3. while held: a push (``push`` times the object's weight, for ``pulse``) and a twist (that
   push at the object's rim), each left out (and cut short) when the hand holds no object;
4. the person snatches the object, pulling it ``snatch`` away from the palm, no lower than it
   was first held, and holds it there; if the hand had already dropped it, the person picks it
   up and holds it out ``snatch`` beside where it was first held;
5. the hand loses the grasp, reaches again and regrasps; the person lets go once more (or
   after ``SNATCH_GIVE_UP`` if the hand kept the object) and the episode is complete once the
   hand has then held it for ``hold_after``; otherwise it ends at ``duration``.

The parameters are an :class:`~wholehand.reaching.episode_spec.EpisodeSpec`. With
``start="table"`` the object instead rests on the table and the hand picks it up with its
table-top grasps; otherwise the table is there to be avoided and to catch a dropped object.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from wholehand import defaults, registry
from wholehand.backends.command import HAND_SERVOS
from wholehand.backends.table import HAND_MARGIN, Table
from wholehand.errors import ConfigError
from wholehand.loop.control_loop import ControlLoop, Cycle, Observer
from wholehand.loop.grasp_loss import GraspLossMonitor
from wholehand.loop.record import Recorder
from wholehand.loop.regulation import ForceRegulation
from wholehand.loop.report import LoopReport
from wholehand.loop.stage import Stage
from wholehand.models.hand import HandModel, load_hand
from wholehand.models.kinematics import HandKinematics, lowest_point
from wholehand.models.object_catalogue import load_object
from wholehand.models.objects import ObjectModel
from wholehand.models.resting import resting_pose
from wholehand.reaching.episode_spec import EpisodeSpec
from wholehand.reaching.person import PERTURBATIONS, ContactHolds, Person, loss_cause
from wholehand.reaching.pipeline import grasp_hand_of, grasp_plans, pipeline_stages
from wholehand.reaching.pregrasp import GraspPlan, hand_clearance, usable_on_table
from wholehand.reaching.stages import (
    PREGRASP,
    REGULATE,
    ReachPlanner,
    ReachStage,
    reacher_faults,
)
from wholehand.timing import percentiles
from wholehand.trials.trial import load_allocator, tracking_filters

FloatArray = npt.NDArray[np.float64]


TABLE_SIZE = (1.5, 1.5)
"""Side lengths of the episode's table [m]: wide enough that a dropped object pushed about by
the hand stays on it."""
ARM_REACH_XY = (0.45, 0.0)
"""Where the person holds the object for an arm, in front of the arm's base [m]."""
START_LIFT = 0.1
"""A floating wrist starts this far above its first pre-grasp [m] ..."""
START_SPREAD = 0.1
"""... moved horizontally by a normal draw with this deviation per axis [m] ..."""
START_CLEARANCE = defaults.PREGRASP_CLEARANCE
"""... and at least this far from the object [m] (a draw that puts the hand into the object, as a
third did on the mustard bottle, starts the simulation by ejecting it at hundreds of rad/s)."""
START_DRAWS = 20
"""Draws tried before starting at the pre-grasp itself."""
STARTS = ("held", "table")
"""Values of :attr:`EpisodeSpec.start`."""
PERSON_SEES = ("stage", "contacts")
"""Values of :attr:`EpisodeSpec.person_sees`."""


def episode_table(hand: HandModel) -> Table:
    """The episode's table: under where the person holds the object, wide enough to catch it."""
    return Table(centre=ARM_REACH_XY if hand.arm_dofs.any() else (0.0, 0.0), size=TABLE_SIZE)


def floating_start(
    hand: HandModel,
    obj: ObjectModel,
    plan: GraspPlan,
    wMo: FloatArray,
    table: Table,
    rng: np.random.Generator,
) -> FloatArray:
    """(4, 4) start pose of a floating wrist: ``START_LIFT`` above the plan's pre-grasp, moved
    horizontally by a normal draw of ``START_SPREAD`` per axis, drawn again until the hand at
    the pre-grasp's angles clears the object by ``START_CLEARANCE`` and the table by
    ``HAND_MARGIN``; after ``START_DRAWS`` draws, the pre-grasp itself (clear by
    construction)."""
    oMw = np.linalg.inv(wMo)
    for _ in range(START_DRAWS):
        wMb = wMo @ plan.oMb_pre
        wMb[:3, 3] += np.array([0.0, 0.0, START_LIFT]) + START_SPREAD * np.r_[rng.normal(size=2), 0]
        clear = hand_clearance(hand, obj, plan.q_pre, oMw @ wMb) >= START_CLEARANCE
        if clear and lowest_point(hand, plan.q_pre, wMb) >= table.top + HAND_MARGIN:
            return wMb
    return wMo @ plan.oMb_pre


@dataclass
class EpisodeScene:
    """An episode's models, its seeded random stream and its MuJoCo scene, before any cycle."""

    hand: HandModel
    grasp_hand: HandModel
    """The hand whose grasps the plans are (an assembly's hand)."""
    obj: ObjectModel
    table: Table
    rng: np.random.Generator
    """The episode's random stream, after the start's draws (the person draws from it next)."""
    plans: list[GraspPlan]
    wMo: FloatArray
    """(4, 4) the object's start pose, world frame."""
    backend: Any
    """The MuJoCo backend: the hand at its start, the object at ``wMo``, gravity on."""
    on_table: bool


def episode_scene(
    spec: EpisodeSpec,
    hand: HandModel | None = None,
    obj: ObjectModel | None = None,
    plans: list[GraspPlan] | None = None,
) -> EpisodeScene:
    """The scene of ``spec``: the same for equal specs, in ``wholehand reach`` and in
    ``wholehand hw-sim`` (an assembly from its home posture, the fingers at the first plan's
    pre-shape; a floating wrist above the first plan's pre-grasp).

    ``hand``, ``obj`` and ``plans`` replace what ``spec`` names (the models loaded by name, the
    plans of the stored grasps), e.g. to try one grasp before it is stored
    (:mod:`wholehand.reaching.reach_check`).

    Raises:
        ConfigError: a bad spec, or no usable stored grasp.
    """
    _check_spec(spec)
    on_table = spec.start == "table"
    hand = load_hand(spec.hand) if hand is None else hand
    obj = load_object(spec.object) if obj is None else obj
    # An assembly's grasps, pre-grasps and targets are those of its hand alone.
    grasp_hand = grasp_hand_of(hand)
    rng = np.random.default_rng(spec.seed)
    table = episode_table(hand)
    held_at = table.centre
    plans = grasp_plans(grasp_hand, obj, on_table) if plans is None else plans
    if not plans:
        raise ConfigError(f"EpisodeSpec: no grasp plan of {obj.name!r} to reach for")

    start = plans[int(rng.integers(len(plans)))]
    if on_table:  # resting on the face the first plan was made on, turned at random
        yaw = rng.uniform(0.0, 2.0 * np.pi)
        if start.table_up is None:
            raise ConfigError(
                f"grasp {start.grasp_id} of {obj.name!r} for {grasp_hand.name!r} is in the "
                "table-top folder but has no table_up (its resting face); generate it with "
                "`wholehand grasps generate --on-table`"
            )
        wMo = resting_pose(obj, start.table_up, yaw, held_at, table.top)
    else:
        wMo = np.eye(4)
        wMo[:3, 3] = [*held_at, table.top]
        wMo[2, 3] += spec.hold_height
    if hand.arm_dofs.any():  # an arm: from its home posture, fingers at the pre-shape
        placement: dict[str, Any] = {"q_init": _arm_start(hand, grasp_hand, start)}
    else:  # a floating wrist: above the pre-grasp, offset at random, clear of everything
        wMb0 = floating_start(hand, obj, start, wMo, table, rng)
        placement = {"q_init": start.q_pre, "wMb": wMb0, "base": "floating"}
    backend = registry.load(
        "backends",
        "mujoco",
        hand=hand,
        obj=obj,
        wMo_init=wMo,
        gravity=True,
        table=table,
        hand_servo=spec.hand_servo,
        **placement,
    )
    return EpisodeScene(hand, grasp_hand, obj, table, rng, plans, wMo, backend, on_table)


def _check_spec(spec: EpisodeSpec) -> None:
    """Raise :class:`ConfigError` for a bad rate, start, push or twist."""
    if not (math.isfinite(spec.rate) and spec.rate > 0):
        raise ConfigError(f"EpisodeSpec: rate must be > 0 [Hz], got {spec.rate!r}")
    if spec.start not in STARTS:
        raise ConfigError(f"EpisodeSpec: start must be one of {STARTS}, got {spec.start!r}")
    if spec.hand_servo not in HAND_SERVOS:
        raise ConfigError(
            f"EpisodeSpec: hand_servo must be one of {HAND_SERVOS}, got {spec.hand_servo!r}"
        )
    if spec.person_sees not in PERSON_SEES:
        raise ConfigError(
            f"EpisodeSpec: person_sees must be one of {PERSON_SEES}, got {spec.person_sees!r}"
        )
    for name in ("push", "twist"):
        value = getattr(spec, name)
        if not (math.isfinite(value) and value >= 0.0):
            raise ConfigError(f"EpisodeSpec: {name} must be >= 0 [object weights], got {value!r}")
    timed = (("tracker_rate", "Hz"), ("tracker_latency", "s"), ("tracker_predict", "s"))
    for name, unit in (*timed, ("qp_deadline", "s")):
        value = getattr(spec, name)
        if not (math.isfinite(value) and value >= 0.0):
            raise ConfigError(f"EpisodeSpec: {name} must be >= 0 [{unit}] (0: none), got {value!r}")


def _arm_start(hand: HandModel, grasp_hand: HandModel, start: GraspPlan) -> FloatArray:
    """(n_q,) an assembly's start: the arm at its home, the fingers at ``start``'s pre-shape."""
    q0 = np.zeros(hand.nq)
    for name, value in zip(hand.config.arm_joints, hand.config.arm_home, strict=True):
        q0[hand.model.joints[hand.model.getJointId(name)].idx_q] = value
    for name in grasp_hand.joint_names:
        i = grasp_hand.model.joints[grasp_hand.model.getJointId(name)].idx_q
        q0[hand.model.joints[hand.model.getJointId(name)].idx_q] = start.q_pre[i]
    return q0


def run_episode(
    spec: EpisodeSpec,
    samples: bool = False,
    record: bool = False,
    observers: Sequence[Observer] = (),
    scene: EpisodeScene | None = None,
) -> dict[str, Any]:
    """Run one episode; returns its summary (events, transitions, counts, timings), with every
    cycle's and reacher step's compute time [us] (``cycle_samples_us``, ``reacher_samples_us``)
    if ``samples``, and the :class:`~wholehand.loop.record.RunRecord` of every cycle
    (``record``, not JSON) if ``record``. ``observers`` see every cycle too (a viewer).
    ``scene``: start from this scene of ``spec`` (:func:`episode_scene`, e.g. with models and
    plans of its own) instead of building it."""
    scene = episode_scene(spec) if scene is None else scene
    hand, obj, backend = scene.hand, scene.obj, scene.backend
    stages, reaching = _episode_stages(spec, scene)
    inertia = float(np.linalg.eigvalsh(np.asarray(obj.inertia)).max())
    rim = 0.5 * float(np.max(obj.extents))
    person = Person(
        spec,
        backend,
        scene.wMo,
        scene.rng,
        (obj.mass, inertia),
        hand.palm_link,
        rim,
        scene.on_table,
        holds=ContactHolds(hand, backend) if spec.person_sees == "contacts" else None,
    )
    timer = _CycleTimes()
    watchers: list[Observer] = [person, timer, *observers]
    recorder = None
    if record:
        loss = GraspLossMonitor(hand, obj, stop_on_loss=False)
        meta = {"spec": asdict(spec), "kind": "reach episode", "table": asdict(scene.table)}
        recorder = Recorder(loss, meta=meta)
        watchers += [loss, recorder]
    filters = []
    if spec.tracker_rate > 0.0:  # the pose a tracker gives, as on a robot
        tracking = {
            "rate_hz": spec.tracker_rate,
            "latency_s": spec.tracker_latency,
            "predict_s": spec.tracker_predict,
        }
        filters = tracking_filters(tracking, obj.com)
    loop = ControlLoop(
        backend, hand, obj, stages, rate=spec.rate, filters=filters, observers=watchers
    )
    report = loop.run(spec.duration)
    reacher_us = [1e6 * t for stage in reaching for t in stage.reacher_times]
    summary = _episode_summary(spec, scene, report, person, timer, reacher_us)
    summary["reacher_faults"] = reacher_faults(reaching)
    if samples:
        summary["cycle_samples_us"] = timer.times
        summary["reacher_samples_us"] = reacher_us
    if recorder is not None:
        summary["record"] = recorder.record
    return summary


def _episode_stages(
    spec: EpisodeSpec, scene: EpisodeScene
) -> tuple[dict[str, Stage], tuple[ReachStage, ReachStage]]:
    """The stage machine of an episode (the pipeline's stages) and its reaching stages, with
    the plug-ins of ``spec`` loaded and their compiled kernels run once."""
    hand, grasp_hand, obj, table = scene.hand, scene.grasp_hand, scene.obj, scene.table
    kin = HandKinematics(grasp_hand)  # one for every check: the stages check in their cycles

    def usable(plan: GraspPlan, wMo_now: FloatArray) -> bool:
        return usable_on_table(grasp_hand, plan, wMo_now, table, HAND_MARGIN, kin)

    estimator = registry.load("contact_estimators", spec.estimator, hand=hand, obj=obj)
    # Passed only when asked for, so that a reacher without the option still loads.
    avoid = {"self_collision": True} if spec.self_collision else {}
    reacher = registry.load("reachers", spec.reacher, hand=hand, obj=obj, table=table, **avoid)
    planner = ReachPlanner(scene.plans, usable)
    # On the table the table carries the weight: balancing it would have the fingers lift the
    # object off its support (measured: the box rose 4 mm and the QP's p99 went to 10-24 ms).
    balance = spec.balance_weight and not scene.on_table
    weight = obj.mass * np.asarray(defaults.GRAVITY_VECTOR) if balance else None
    options = {"options": {"deadline": spec.qp_deadline}} if spec.qp_deadline > 0.0 else {}
    allocator = load_allocator(spec.allocator, hand, options)
    compensate = spec.gravity_compensation
    regulation = ForceRegulation(
        hand, obj, estimator, allocator, weight=weight, gravity_compensation=compensate
    )
    return pipeline_stages(
        hand, grasp_hand, obj, planner, estimator, reacher, regulation, compensate
    )


def _episode_summary(
    spec: EpisodeSpec,
    scene: EpisodeScene,
    report: LoopReport,
    person: Person,
    timer: _CycleTimes,
    reacher_us: list[float],
) -> dict[str, Any]:
    """An episode's summary: its events, transitions, grasps, losses and their causes,
    regrasps, and the timings [us] of its cycles and reacher steps."""
    losses = [t for t in report.transitions if t.source == REGULATE and t.target == PREGRASP]
    grasps = [t for t in report.transitions if t.target == REGULATE]
    recovered = sum(any(g.t > loss.t for g in grasps) for loss in losses)
    return {
        "spec": asdict(spec),
        "complete": person.complete,
        "skipped_perturbations": person.skipped,
        "mount": "arm" if scene.hand.arm_dofs.any() else "floating wrist",
        "duration_s": scene.backend.time,
        "perturbations": sum(e.what.startswith(PERTURBATIONS) for e in person.events),
        "grasps": len(grasps),
        "time_to_grasp_s": grasps[0].t if grasps else None,
        "losses": len(losses),
        "loss_causes": [loss_cause(person.events, loss.t) for loss in losses],
        "recovered": recovered,
        "events": [asdict(e) for e in person.events],
        "transitions": [t.__dict__ for t in report.transitions],
        "notes": [n.__dict__ for n in report.notes],
        "cycle_us": timer.summary(),
        "reacher_us": percentiles(reacher_us),
        "loop": report.as_dict(),
        "mujoco_warnings": scene.backend.warnings(),
    }


class _CycleTimes(Observer):
    """Compute time of every cycle by stage kind [us]."""

    def __init__(self) -> None:
        self.times: dict[str, list[float]] = {"reach": [], "regulate": []}

    def on_cycle(self, cycle: Cycle) -> str | None:
        kind = "regulate" if cycle.stage == REGULATE else "reach"
        self.times[kind].append(cycle.cycle_time * 1e6)
        return None

    def summary(self) -> dict[str, dict[str, float]]:
        return {kind: percentiles(v) for kind, v in self.times.items() if v}
