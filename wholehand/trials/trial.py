"""One perturbation trial of a stored grasp: build the scene and the stage, run the protocol."""

from __future__ import annotations

import inspect
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand import defaults, registry
from wholehand.allocation.base import hand_keywords
from wholehand.backends.base import Backend, HasGroundTruth, ReportsWarnings
from wholehand.errors import ConfigError
from wholehand.grasps.store import Grasp, load_grasps
from wholehand.loop.control_loop import ControlLoop, Observer
from wholehand.loop.filters import (
    ConstantPoseError,
    ObservationFilter,
    PoseDropout,
    PoseNoise,
    PosePredictor,
    PoseTracker,
)
from wholehand.loop.grasp_loss import GraspLossMonitor
from wholehand.loop.record import Recorder, RunRecord
from wholehand.loop.regulation import EstimateAt, ForceRegulation
from wholehand.models.hand import HandModel, load_hand
from wholehand.models.object_catalogue import load_object
from wholehand.models.objects import ObjectModel
from wholehand.trials.disturbance import DisturbanceDriver, DisturbanceProtocol
from wholehand.trials.protocol import PerturbationProtocol, ProtocolDriver

FloatArray = npt.NDArray[np.float64]

CONTROL_RATE = 200.0
"""Default control rate in simulation time [Hz]; the simulation steps finer in between."""

POSE_ERROR_KEYS = ("rot_deg", "trans_mm", "seed")
"""Keys of :attr:`TrialSpec.pose_error`."""
TRACKING_KEYS = (
    "rate_hz",
    "latency_s",
    "noise_mm",
    "noise_deg",
    "noise_seed",
    "dropouts",
    "predict_s",
)
"""Keys of :attr:`TrialSpec.tracking`."""


@dataclass(frozen=True)
class TrialSpec:
    """Everything that defines one trial; equal specs give equal records."""

    hand: str = "allegro_right"
    object: str = "077_rubiks_cube"
    grasp: int = 0
    """Index into the stored grasps of (hand, object, grasp_type)."""
    grasp_type: str = "power"
    """Grasp style of the stored grasp file: ``power`` or e.g. ``precision``."""
    grasp_file: str = ""
    """A grasp file to take the grasp from instead (:mod:`wholehand.grasps.store`); empty: the
    hand's stored grasps of the object and style."""
    estimator: str | type = "mesh_sdf"
    """Contact-estimator plug-in: a registered name or a class."""
    allocator: str | type = "qp"
    """Allocator plug-in: a registered name or a class."""
    theta_deg: float = 60.0
    seed: int = 0
    control_rate: float = CONTROL_RATE
    gravity: bool = False
    balance_weight: bool = False
    """Force regulation balances the object's known weight (``ForceRegulation(weight=...)``,
    the allocator then needs ``supports_external_wrench``); only with ``gravity``. False: the
    paper's quasi-static balance of no external wrench."""
    gravity_compensation: bool = False
    """The hand's actuators also hold their own links against gravity
    (``ForceRegulation(gravity_compensation=True)``, the allocator then needs
    ``supports_tau_bias``); only with ``gravity``. False: the paper's ``tau = J^T f``."""
    backend: str | type = "mujoco"
    """Backend plug-in: a registered name or a class."""
    estimator_params: dict[str, Any] = field(default_factory=dict)
    allocator_params: dict[str, Any] = field(default_factory=dict)
    backend_params: dict[str, Any] = field(default_factory=dict)
    """Keyword options of the backend, e.g. ``{"self_collision": False}`` for ``mujoco``
    (:class:`~wholehand_plugins.mujoco.scene_options.SceneOptions`)."""
    protocol_params: dict[str, Any] = field(default_factory=dict)
    """Overrides of :class:`PerturbationProtocol` fields (e.g. shorter stages for tests)."""
    pose_error: dict[str, Any] = field(default_factory=dict)
    """Constant error of the object pose given to the controller (paper Sec. IV-B-2):
    ``{"rot_deg": R, "trans_mm": T, "seed": S}``, see :func:`pose_error_offset`. Empty: none."""
    tracking: dict[str, Any] = field(default_factory=dict)
    """How the object pose reaches the controller (:func:`tracking_filters`): ``rate_hz`` and
    ``latency_s`` (a tracker, :class:`~wholehand.loop.filters.PoseTracker`; rate 200 Hz if only
    the latency is given), ``noise_mm``,
    ``noise_deg`` and ``noise_seed`` (:class:`~wholehand.loop.filters.PoseNoise`), ``dropouts``
    (``[[start_s, duration_s], ...]``), ``predict_s`` (the controller carries each pose
    forward at the object's velocity, at most this long:
    :class:`~wholehand.loop.filters.PosePredictor`). Empty: the exact pose every cycle."""
    disturbance: str = ""
    """A fast disturbance (:data:`~wholehand.trials.disturbance.DISTURBANCES`) instead of the
    perturbation protocol: settle, the push, the recovery (``theta_deg`` then has no effect;
    ``seed`` picks the push's direction or finger). Empty: the perturbation protocol."""
    compute_delay: bool = False
    """Simulated real time: each command takes effect after the cycle's compute time measured
    on this computer (:class:`~wholehand.loop.control_loop.ControlLoop`'s ``compute_delay``), so
    the trial depends on the computer's speed. False: computing takes no simulated time."""
    estimate_at: str = "object_stamp"
    """Where contacts are estimated: ``"object_stamp"`` (at q(stamp_object), the paper's) or
    ``"current"`` (:class:`~wholehand.loop.regulation.ForceRegulation`)."""


def pose_error_offset(
    pose_error: dict[str, Any], centre: npt.ArrayLike = (0.0, 0.0, 0.0)
) -> FloatArray | None:
    """(4, 4) object-frame offset ``T`` of a constant pose error, ``wMo_given = wMo_true @ T``.

    ``T`` rotates by ``rot_deg`` [deg] about a random unit axis through ``centre`` (3,) [m,
    object frame; trials pass the object's centre of mass] and translates by ``trans_mm`` [mm]
    along a random unit direction: a point ``p`` of the object frame goes to
    ``R (p - centre) + centre + t``, so ``centre`` itself moves by exactly ``trans_mm``. Axis and
    direction are in the object frame and drawn from ``seed`` (default 0): the same seed gives
    the same directions at every magnitude. Returns None for an empty dict or zero magnitudes
    (the controller then sees the true pose, unchanged).

    Rotating about the centre of mass rather than the mesh origin keeps the error's effect
    independent of where a mesh file happens to put its origin (YCB scans put it up to 8 cm
    from the centre of mass).

    Raises:
        ConfigError: unknown keys or negative / non-finite magnitudes.
    """
    unknown = set(pose_error) - set(POSE_ERROR_KEYS)
    if unknown:
        raise ConfigError(
            f"pose_error has unknown keys {sorted(unknown)}; use {list(POSE_ERROR_KEYS)}"
        )
    rot = float(pose_error.get("rot_deg", 0.0))
    trans = float(pose_error.get("trans_mm", 0.0))
    if not (np.isfinite(rot) and np.isfinite(trans) and rot >= 0.0 and trans >= 0.0):
        raise ConfigError(
            f"pose_error: rot_deg and trans_mm must be finite and >= 0, got {rot!r}, {trans!r}"
        )
    if rot == 0.0 and trans == 0.0:
        return None
    c = np.asarray(centre, dtype=float).reshape(3)
    rng = np.random.default_rng(int(pose_error.get("seed", 0)))
    axis, direction = rng.standard_normal((2, 3))
    R = pin.exp3(np.deg2rad(rot) * axis / np.linalg.norm(axis))
    offset = np.eye(4)
    offset[:3, :3] = R
    offset[:3, 3] = c - R @ c + 1e-3 * trans * direction / np.linalg.norm(direction)
    return offset


def tracking_filters(
    tracking: dict[str, Any], centre: npt.ArrayLike = (0.0, 0.0, 0.0)
) -> list[ObservationFilter]:
    """The observation filters of :attr:`TrialSpec.tracking`, in the order a tracker applies
    them: frames at a rate with a latency, noise on each frame, dropouts; then the
    controller's prediction.

    Raises:
        ConfigError: an unknown key or a bad value (named).
    """
    unknown = set(tracking) - set(TRACKING_KEYS)
    if unknown:
        raise ConfigError(f"tracking has unknown keys {sorted(unknown)}; use {list(TRACKING_KEYS)}")

    def number(key: str, default: float) -> float:
        value = tracking.get(key, default)
        try:
            return float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"tracking: {key} must be a number, got {value!r}") from None

    out: list[ObservationFilter] = []
    if "rate_hz" in tracking or "latency_s" in tracking:
        out.append(PoseTracker(number("rate_hz", CONTROL_RATE), number("latency_s", 0.0)))
    noise_mm, noise_deg = number("noise_mm", 0.0), number("noise_deg", 0.0)
    if noise_mm or noise_deg:
        out.append(PoseNoise(noise_mm, noise_deg, int(number("noise_seed", 0)), centre))
    if tracking.get("dropouts"):
        try:
            intervals = [(float(a), float(b)) for a, b in tracking["dropouts"]]
        except (TypeError, ValueError):
            raise ConfigError(
                f"tracking: dropouts must be [[start_s, duration_s], ...], got "
                f"{tracking['dropouts']!r}"
            ) from None
        out.append(PoseDropout(intervals))
    if tracking.get("predict_s"):
        out.append(PosePredictor(number("predict_s", 0.0)))
    return out


@dataclass(frozen=True)
class TrialSetup:
    """A trial ready to run: the backend at the grasp, the regulation stage, the filters."""

    hand: HandModel
    obj: ObjectModel
    backend: Backend
    regulation: ForceRegulation
    grasp: Grasp
    filters: list[ObservationFilter]
    """What the controller sees of the object: pose error, then the tracker's filters."""
    n_contacts_gt_init: int | None
    """Simulator contacts at the initial state (None when the backend has no ground truth)."""

    def loop(
        self, observers: Sequence[Observer], rate: float = CONTROL_RATE, compute_delay: bool = False
    ) -> ControlLoop:
        """A control loop of the trial's stage, filters and the given observers."""
        return ControlLoop(
            self.backend,
            self.hand,
            self.obj,
            self.regulation,
            rate=rate,
            filters=self.filters,
            observers=observers,
            compute_delay=compute_delay,
        )


def set_up_trial(
    spec: TrialSpec,
    hand: HandModel | None = None,
    obj: ObjectModel | None = None,
    grasp: Grasp | None = None,
) -> TrialSetup:
    """Backend at the stored grasp (or at ``grasp``, if given) and the spec's plug-ins in a
    force-regulation stage.

    Raises:
        ConfigError: a grasp index past the stored grasps, bad filter parameters, or an
            allocator that needs ground truth over a backend without it.
    """
    hand = hand or load_hand(spec.hand)
    obj = obj or load_object(spec.object)
    grasp = grasp or stored_grasp(spec)
    if spec.balance_weight and not spec.gravity:
        raise ConfigError(
            "balance_weight=True needs gravity=True: without gravity the object has no weight "
            "to balance, and the hand would push it with the weight's force"
        )
    if spec.gravity_compensation and not spec.gravity:
        raise ConfigError(
            "gravity_compensation=True needs gravity=True: without gravity the links weigh "
            "nothing, and the torques would be those of the default gravity all the same"
        )
    filters: list[ObservationFilter] = []
    offset = pose_error_offset(spec.pose_error, obj.com)
    if offset is not None:
        filters.append(ConstantPoseError(offset))
    filters += tracking_filters(spec.tracking, obj.com)
    backend = registry.load(
        "backends",
        spec.backend,
        hand=hand,
        obj=obj,
        q_init=grasp.q_array(hand),
        wMo_init=grasp.object_pose(hand.wMb),
        gravity=spec.gravity,
        **spec.backend_params,
    )
    estimator = registry.load(
        "contact_estimators", spec.estimator, hand=hand, obj=obj, **spec.estimator_params
    )
    allocator = load_allocator(spec.allocator, hand, spec.allocator_params)
    if allocator.needs_ground_truth and not isinstance(backend, HasGroundTruth):
        raise ConfigError(
            f"allocator {type(allocator).__name__} needs ground-truth contacts at "
            f"initialisation; backend {type(backend).__name__} has no ground_truth_contacts()"
        )
    weight = obj.mass * np.asarray(defaults.GRAVITY_VECTOR) if spec.balance_weight else None
    regulation = ForceRegulation(
        hand,
        obj,
        estimator,
        allocator,
        cast(EstimateAt, spec.estimate_at),
        weight=weight,
        gravity_compensation=spec.gravity_compensation,
    )
    n_gt = len(backend.ground_truth_contacts()) if isinstance(backend, HasGroundTruth) else None
    return TrialSetup(hand, obj, backend, regulation, grasp, filters, n_gt)


def stored_grasp(spec: TrialSpec) -> Grasp:
    """The spec's grasp: number ``grasp`` of its grasp file, or of the hand's stored grasps of
    the object and style.

    Raises:
        ConfigError: no grasp of that number.
    """
    if spec.grasp_file:
        grasps, source = load_grasps(spec.grasp_file), spec.grasp_file
    else:
        grasps = load_grasps(spec.hand, spec.object, spec.grasp_type)
        source = f"the stored {spec.grasp_type} grasps of {spec.object!r} for {spec.hand!r}"
    if not 0 <= spec.grasp < len(grasps):
        raise ConfigError(
            f"grasp {spec.grasp} does not exist: {source} holds {len(grasps)} grasps "
            f"(0..{len(grasps) - 1})"
        )
    return grasps[spec.grasp]


def load_allocator(name: str | type, hand: HandModel, params: dict[str, Any]) -> Any:
    """An allocator plug-in built with the user's ``params`` and those of the hand's keywords
    (:func:`~wholehand.allocation.base.hand_keywords`) that its constructor accepts."""
    cls = registry.get_class("allocators", name)
    signature = inspect.signature(cls)
    takes_any = any(p.kind is p.VAR_KEYWORD for p in signature.parameters.values())
    accepted = {
        k: v for k, v in hand_keywords(hand).items() if takes_any or k in signature.parameters
    }
    return registry.load("allocators", cls, **{**accepted, **params})


def run_trial(
    spec: TrialSpec,
    hand: HandModel | None = None,
    obj: ObjectModel | None = None,
    stop_on_loss: bool = True,
    observers: Sequence[Observer] = (),
    grasp: Grasp | None = None,
) -> RunRecord:
    """Run the perturbation protocol on one stored grasp (or on ``grasp``, if given); the
    record's meta holds the spec and the loop's report (``meta["loop"]``: statuses, faults,
    stage errors with tracebacks).

    ``observers`` see every cycle after the protocol, the grasp-loss check and the recorder
    (e.g. a live viewer).
    """
    started = time.perf_counter()
    protocol: PerturbationProtocol | DisturbanceProtocol
    meta: dict[str, Any] = {"control_rate": spec.control_rate, "seed": spec.seed}
    if spec.disturbance:
        protocol = DisturbanceProtocol(spec.disturbance, spec.seed, **spec.protocol_params)
        meta["disturbance"] = spec.disturbance
    else:
        protocol = PerturbationProtocol(spec.theta_deg, spec.seed, **spec.protocol_params)
        meta["theta_deg"] = protocol.theta_deg
    protocol.check_rate(spec.control_rate)
    trial = set_up_trial(spec, hand, obj, grasp)
    driver: ProtocolDriver | DisturbanceDriver
    if isinstance(protocol, DisturbanceProtocol):
        driver = DisturbanceDriver(protocol, trial.hand, trial.obj)
    else:
        driver = ProtocolDriver(protocol, trial.obj)
    loss = GraspLossMonitor(trial.hand, trial.obj, stop_on_loss)
    recorder = Recorder(loss, driver, meta)
    loop = trial.loop([driver, loss, recorder, *observers], spec.control_rate, spec.compute_delay)
    report = loop.run(protocol.duration)
    record = recorder.record
    if isinstance(driver, DisturbanceDriver):
        record.meta["disturbance_event"] = driver.event
    backend = trial.backend
    record.meta.update(
        {
            "spec": {k: getattr(v, "__name__", v) for k, v in spec.__dict__.items()},
            "grasp_id": trial.grasp.id,
            "n_contacts_gt_init": trial.n_contacts_gt_init,
            "wall_time_s": time.perf_counter() - started,
            "sim_time_s": float(backend.time),
            "loop": report.as_dict(),
            "degenerate_normals": trial.regulation.degenerate_normals,
            # MuJoCo's run-time warnings; bad_qacc means it diverged and reset the state.
            "sim_warnings": backend.warnings() if isinstance(backend, ReportsWarnings) else {},
        }
    )
    return record
