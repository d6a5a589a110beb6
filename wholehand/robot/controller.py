"""``wholehand control``: the controller on a robot over the ``ros2`` backend.

On an arm-hand assembly it runs the whole pipeline, the same stage machine as ``wholehand reach``
(:mod:`wholehand.reaching.pipeline`): reach the pre-grasp, reach the grasp, regulate, back to
reaching after a loss, and home while the object is out of the arm's workspace. On a hand alone
it regulates a grasp that is already in the hand (:class:`~wholehand.loop.regulation.
ForceRegulation`). Either way the same :class:`~wholehand.loop.control_loop.ControlLoop` as in
simulation runs, now on the wall clock of :class:`~wholehand_plugins.ros2_backend.Ros2Backend`,
until ``duration`` has passed or the process is asked to stop (SIGINT, SIGTERM); the backend's
last commands (the arm held, the hand's torques ramped to zero) follow on every exit. It reports
the loop's statuses and stage transitions, the messages received and rejected, and how often
each safety rule acted.
"""

from __future__ import annotations

import inspect
import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
import numpy.typing as npt

from wholehand import defaults, registry
from wholehand.allocation.base import Allocator
from wholehand.allocation.options import SolveOptions
from wholehand.backends.table import HAND_MARGIN
from wholehand.contacts.base import ContactEstimator
from wholehand.errors import ConfigError
from wholehand.loop.control_loop import ControlLoop, Cycle, Observer
from wholehand.loop.filters import ObservationFilter, PosePredictor
from wholehand.loop.gate import ObservationGate
from wholehand.loop.regulation import AllocateEvery, EstimateAt, ForceRegulation
from wholehand.loop.stage import Stage
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel
from wholehand.reaching.pipeline import (
    RobotRules,
    always_usable,
    grasp_hand_of,
    grasp_plans,
    home_configuration,
    pipeline_stages,
)
from wholehand.reaching.pregrasp import GraspPlan, usable_on_table
from wholehand.reaching.stages import (
    PREGRASP,
    REGULATE,
    HoldStage,
    ReachPlanner,
    reacher_faults,
)
from wholehand.robot.late_cycles import LateCycles
from wholehand.robot.realtime import check_priority, frozen_heap, realtime_priority
from wholehand.robot.stopping import signals_set
from wholehand.ros2.config import HardwareConfig
from wholehand.ros2.inputs import model_joint_name
from wholehand.timing import percentiles
from wholehand.trials.trial import load_allocator

FloatArray = npt.NDArray[np.float64]

CYCLE_TIMES_KEPT = 100_000
"""Cycle times the report's percentiles cover (the latest; a controller may run for hours)."""

QP_DEADLINE = 0.002
"""Default time budget of one allocation on a robot [s]: 40 % of the 5 ms period at 200 Hz."""

AFTER_MISS = 1.5
"""The budget of an allocation right after a missed one, in ``qp_deadline``s (3 ms, 60 % of the
period, at the defaults): near a loss the misses then come singly, not in runs."""


@dataclass(frozen=True)
class ControllerSpec:
    """The controller's plug-ins and how it allocates between poses."""

    estimator: str = "mesh_sdf"
    allocator: str = "qp"
    estimate_at: str = "object_stamp"
    """``object_stamp``: contacts at q(stamp of the pose) (paper); ``current``: at the newest q."""
    allocate_every: str = "cycle"
    """``cycle``: every control cycle at the current q; ``pose``: once per pose (paper)."""
    estimator_params: dict[str, Any] = field(default_factory=dict)
    allocator_params: dict[str, Any] = field(default_factory=dict)
    qp_deadline: float | None = QP_DEADLINE
    """Time budget of one allocation [s], for allocators that take solve options (the ``qp``
    family): past it the loop keeps the last feasible torque and counts a ``deadline`` cycle."""
    qp_deadline_after_miss: float | None = None
    """Time budget of an allocation right after a ``deadline`` cycle [s], at least
    ``qp_deadline`` (None: :data:`AFTER_MISS` times ``qp_deadline``)."""
    screen_edges: bool = True
    """Screen the pyramid-edge weights too, for allocators that take solve options (the ``qp``
    family): smaller problems near a loss, so fewer deadline cycles."""
    reacher: str = "mink"
    """The reacher plug-in of the pipeline (an arm-hand assembly only)."""
    balance_weight: bool = True
    """Pipeline: force regulation balances the object's known weight (as ``wholehand
    reach``)."""
    gravity_compensation: bool = True
    """Pipeline: the hand's torques hold its own links against gravity (as ``wholehand
    reach``)."""


def controller_allocator(spec: ControllerSpec, hand: HandModel) -> Allocator:
    """The spec's allocator, with the controller's ``qp_deadline`` (and the budget after a
    miss) and ``screen_edges`` in the solve options of allocators that take them (the ``qp``
    family). The user's ``allocator_params["options"]`` win: a mapping's keys over the
    controller's, a :class:`~wholehand.allocation.options.SolveOptions` as it is."""
    params = dict(spec.allocator_params)
    takes = inspect.signature(registry.get_class("allocators", spec.allocator)).parameters
    if "options" in takes and not isinstance(params.get("options"), SolveOptions):
        options = {"screen_edges": spec.screen_edges, **(params.get("options") or {})}
        if spec.qp_deadline is not None:
            options.setdefault("deadline", spec.qp_deadline)
            after_miss = spec.qp_deadline_after_miss
            if options["deadline"] == spec.qp_deadline:
                options.setdefault(
                    "deadline_after_miss",
                    AFTER_MISS * spec.qp_deadline if after_miss is None else after_miss,
                )
        params["options"] = options
    return cast(Allocator, load_allocator(spec.allocator, hand, params))


def _regulation(
    hand: HandModel,
    obj: ObjectModel,
    spec: ControllerSpec,
    estimator: ContactEstimator,
    allocator: Allocator,
    weight: FloatArray | None = None,
    gravity_compensation: bool = False,
) -> ForceRegulation:
    """Force regulation with the spec's estimation stamp and allocation schedule."""
    return ForceRegulation(
        hand,
        obj,
        estimator,
        allocator,
        cast(EstimateAt, spec.estimate_at),
        allocate_every=cast(AllocateEvery, spec.allocate_every),
        weight=weight,
        gravity_compensation=gravity_compensation,
    )


def pipeline_for_robot(
    hand: HandModel,
    obj: ObjectModel,
    config: HardwareConfig,
    spec: ControllerSpec,
    estimator: ContactEstimator,
    allocator: Allocator,
) -> dict[str, Stage]:
    """The stage machine of ``wholehand reach`` for an arm-hand on a robot: its workspace and
    table, home posture and pose timeout from ``config``.

    Raises:
        ConfigError: the config gives the arm no command topic or no workspace.
    """
    workspace = config.workspace
    if not config.topic("arm_command") or workspace is None:
        raise ConfigError(
            f"{config.path or 'hardware config'}: {hand.name!r} is an arm-hand assembly: set "
            "[topics] arm_command, [arm] joints and [workspace] (docs/hardware.md), or give the "
            "hand alone (--hand) to regulate a grasp already in it"
        )
    grasp_hand = grasp_hand_of(hand)
    table = workspace.table
    kin = HandKinematics(grasp_hand)

    def usable(plan: GraspPlan, wMo: FloatArray) -> bool:
        assert table is not None
        return usable_on_table(grasp_hand, plan, wMo, table, HAND_MARGIN, kin)

    planner = ReachPlanner(grasp_plans(grasp_hand, obj), always_usable if table is None else usable)
    reacher = registry.load("reachers", spec.reacher, hand=hand, obj=obj, table=table)
    weight = obj.mass * np.asarray(defaults.GRAVITY_VECTOR) if spec.balance_weight else None
    regulation = _regulation(
        hand, obj, spec, estimator, allocator, weight, spec.gravity_compensation
    )
    arm_home = None
    if config.arm.home is not None:  # [arm] home is in the arm controller's order
        given = {
            model_joint_name(hand, config, n): v
            for n, v in zip(config.arm.joints, config.arm.home, strict=True)
        }
        arm_home = tuple(given[n] for n in hand.config.arm_joints)
    robot = RobotRules(
        workspace, config.safety.pose_timeout, home_configuration(hand, grasp_hand, arm_home)
    )
    stages, _ = pipeline_stages(
        hand,
        grasp_hand,
        obj,
        planner,
        estimator,
        reacher,
        regulation,
        spec.gravity_compensation,
        robot,
    )
    return stages


class _StopWhen(Observer):
    """Ends the run when an event is set (a signal asked the controller to stop) or ``stop()``
    returns something other than None."""

    def __init__(self, event: threading.Event, stop: Callable[[], object] | None) -> None:
        self.event, self.stop = event, stop
        self.cycle_times: deque[float] = deque(maxlen=CYCLE_TIMES_KEPT)

    def on_cycle(self, cycle: Cycle) -> str | None:
        self.cycle_times.append(cycle.cycle_time)
        if self.event.is_set() or (self.stop is not None and self.stop() is not None):
            return "stopped"
        return None


STATUS_PERIOD = 1.0
"""The controller repeats its stage on the status topic this often [s] (and on each change), so
that a listener that joins late learns it."""


class StatusPublisher(Observer):
    """Publishes the stage each cycle ran on the backend's status topic
    (:meth:`~wholehand_plugins.ros2_backend.Ros2Backend.publish_status`) when it changes and
    every :data:`STATUS_PERIOD` seconds."""

    def __init__(self, publish: Callable[[str], None]) -> None:
        self.publish = publish
        self._stage = ""
        self._sent = -np.inf

    def on_cycle(self, cycle: Cycle) -> str | None:
        if cycle.stage != self._stage or cycle.t - self._sent >= STATUS_PERIOD:
            self.publish(cycle.stage)
            self._stage, self._sent = cycle.stage, cycle.t
        return None


class _AnnounceTransitions(Observer):
    """Calls ``announce`` with a line for each switch between stages as the run goes (an
    operator watches the pipeline's progress; a test waits for a stage instead of a time)."""

    def __init__(self, announce: Callable[[str], None]) -> None:
        self.announce = announce
        self._said = 0
        self._loop: ControlLoop | None = None

    def on_start(self, loop: ControlLoop) -> None:
        self._loop, self._said = loop, 0

    def on_cycle(self, cycle: Cycle) -> str | None:
        assert self._loop is not None
        transitions = self._loop.report.transitions
        for t in transitions[self._said :]:
            self.announce(f"stage {t.source} -> {t.target} at {t.t:.3f} s: {t.reason}")
        self._said = len(transitions)
        return None


STREAM_TIMEOUT = 30.0
"""How long the controller waits for the first joint state and object pose [s]."""


def pose_filters(config: HardwareConfig) -> list[ObservationFilter]:
    """What the controller does to the tracker's poses before the stages see them: carry each
    forward to the joint state's time (``[object_pose] predict``; none with 0)."""
    if config.pose_prediction > 0.0:
        return [PosePredictor(config.pose_prediction)]
    return []


def run_controller(
    hand: HandModel,
    obj: ObjectModel,
    config: HardwareConfig,
    spec: ControllerSpec,
    duration: float | None = None,
    trace: bool = False,
    wait: float = STREAM_TIMEOUT,
    announce: Callable[[str], None] | None = None,
    stop: Callable[[], object] | None = None,
    observers: Sequence[Observer] = (),
) -> dict[str, Any]:
    """Wait for the robot's streams, then run the pipeline (an arm-hand assembly) or force
    regulation (a hand alone) against it; returns a JSON-ready report (``mode``, ``loop`` with
    the stage transitions, ``backend`` counts, ``cycle_time_ms`` percentiles, the
    :class:`~wholehand.robot.late_cycles.LateCycle` records of the cycles past their period in
    ``late_cycles``, the reacher's ``reacher_faults``; with ``trace``,
    the ``trace`` of published torques and every kept cycle's time in ``cycle_times_s``).
    ``announce`` is called with a line once the streams are up and at each switch between
    stages (``stage <from> -> <to> at <t> s: <reason>``); the run also ends on the first
    cycle ``stop()`` returns something other than None.

    Raises:
        ConfigError: no joint state or object pose within ``wait`` [s]; an assembly without an
            arm topic or workspace in ``config``.
    """
    check_priority(config.thread_priority)
    estimator = registry.load(
        "contact_estimators", spec.estimator, hand=hand, obj=obj, **spec.estimator_params
    )
    allocator = controller_allocator(spec, hand)
    pipeline = bool(hand.arm_dofs.any())
    stages: dict[str, Stage] | Stage
    if pipeline:
        stages = pipeline_for_robot(hand, obj, config, spec, estimator, allocator)
    else:
        stages = _regulation(hand, obj, spec, estimator, allocator)
    stopped = threading.Event()
    stopper = _StopWhen(stopped, stop)
    announcer = [] if announce is None else [_AnnounceTransitions(announce)]
    late = LateCycles()
    watchers: list[Observer] = [stopper, late, *announcer, *observers]
    with signals_set(stopped):
        with registry.load(
            "backends", "ros2", hand=hand, obj=obj, config=config, trace=trace
        ) as backend:
            backend.wait_for_streams(wait)
            if announce is not None:
                what = "the pipeline" if pipeline else "regulating"
                announce(
                    f"streams up; {what} at {config.control_rate:g} Hz on "
                    f"{config.topics['torque_command']}"
                )
            gate = ObservationGate(hand)
            status = StatusPublisher(backend.publish_status)
            first = PREGRASP if pipeline else None
            rate = config.control_rate
            loop = ControlLoop(
                backend,
                hand,
                obj,
                stages,
                first=first,
                rate=rate,
                filters=pose_filters(config),
                observers=[*watchers, status],
                gate=gate,
            )
            with frozen_heap(), realtime_priority(config.thread_priority):
                report = loop.run(duration)
        # After the backend's last commands (the exit ramp, when it closed), so they count.
        stats = backend.stats()
        stats["gate_refused"] = dict(gate.refused)
        traced = list(backend.trace or ())
    out: dict[str, Any] = {
        "mode": "pipeline" if pipeline else "regulate",
        "loop": report.as_dict(),
        "backend": stats,
        "degenerate_normals": _regulation_of(stages).degenerate_normals,
        "cycle_time_ms": percentiles(np.asarray(stopper.cycle_times) * 1e3),
        "late_cycles": late.as_list(),
        "reacher_faults": reacher_faults(stages.values()) if isinstance(stages, dict) else {},
    }
    if trace:
        out["trace"] = traced
        out["cycle_times_s"] = list(stopper.cycle_times)
    return out


def _regulation_of(stages: dict[str, Stage] | Stage) -> ForceRegulation:
    """The force regulation of a controller's stages (a hand alone's, or the pipeline's
    hold stage's)."""
    if isinstance(stages, ForceRegulation):
        return stages
    assert isinstance(stages, dict)
    hold = stages[REGULATE]
    assert isinstance(hold, HoldStage)
    return hold.regulation
