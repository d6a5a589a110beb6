"""One perturbation trial of a stored grasp: build the scene, the controller, run the protocol."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand import registry
from wholehand.allocation.baselines import FixedAllocationBaseline
from wholehand.backends.base import HandObjectState
from wholehand.contacts.base import ContactSet
from wholehand.errors import ConfigError
from wholehand.grasps.store import Grasp, load_grasps
from wholehand.loop.controller import CycleResult, ForceRegulationController
from wholehand.loop.protocol import PerturbationProtocol
from wholehand.loop.record import RunRecord
from wholehand.loop.scheduler import CONTROL_RATE, run_protocol
from wholehand.models.hand import HandModel, load_hand
from wholehand.models.objects import ObjectModel, load_object

FloatArray = npt.NDArray[np.float64]

POSE_ERROR_KEYS = ("rot_deg", "trans_mm", "seed")
"""Keys of :attr:`TrialSpec.pose_error`."""


@dataclass(frozen=True)
class TrialSpec:
    """Everything that defines one trial; equal specs give equal records."""

    hand: str = "allegro_right"
    object: str = "077_rubiks_cube"
    grasp: int = 0
    """Index into the stored grasps of (hand, object, grasp_type)."""
    grasp_type: str = "power"
    """Grasp style of the stored grasp file: ``power`` or e.g. ``precision``."""
    estimator: str | type = "mesh_sdf"
    """Contact-estimator plug-in: a registered name or a class."""
    allocator: str | type = "qp"
    """Allocator plug-in: a registered name or a class."""
    theta_deg: float = 60.0
    seed: int = 0
    control_rate: float = CONTROL_RATE
    gravity: bool = False
    backend: str = "mujoco"
    estimator_params: dict[str, Any] = field(default_factory=dict)
    allocator_params: dict[str, Any] = field(default_factory=dict)
    backend_params: dict[str, Any] = field(default_factory=dict)
    """Keyword options of the backend, e.g. ``{"self_collision": False}`` for ``mujoco``
    (:class:`~wholehand.backends.mujoco_scene.SceneOptions`)."""
    protocol_params: dict[str, Any] = field(default_factory=dict)
    """Overrides of :class:`PerturbationProtocol` fields (e.g. shorter stages for tests)."""
    pose_error: dict[str, Any] = field(default_factory=dict)
    """Constant error of the object pose given to the controller (paper Sec. IV-B-2):
    ``{"rot_deg": R, "trans_mm": T, "seed": S}``, see :func:`pose_error_offset`. Empty: none."""


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


@dataclass(frozen=True)
class TrialSetup:
    """A trial ready to run: the backend at the grasp, the controller, and what was measured."""

    backend: Any
    controller: ForceRegulationController
    grasp: Grasp
    pose_offset: FloatArray | None
    """(4, 4) constant pose error given to the controller, or None."""
    n_contacts_gt_init: int | None
    """MuJoCo contacts at the initial state (None when the backend has no ground truth)."""


def set_up_trial(
    spec: TrialSpec, hand: HandModel | None = None, obj: ObjectModel | None = None
) -> TrialSetup:
    """Backend at the stored grasp, the spec's plug-ins in a controller, baselines initialised."""
    hand = hand or load_hand(spec.hand)
    obj = obj or load_object(spec.object)
    grasps = load_grasps(spec.hand, spec.object, spec.grasp_type)
    if not 0 <= spec.grasp < len(grasps):
        raise ConfigError(
            f"grasp {spec.grasp} does not exist: {spec.object!r} has {len(grasps)} stored "
            f"{spec.grasp_type} grasps for {spec.hand!r} (0..{len(grasps) - 1})"
        )
    grasp = grasps[spec.grasp]
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
    allocator_params = {**_allocator_defaults(hand), **spec.allocator_params}
    allocator = registry.load("allocators", spec.allocator, **allocator_params)
    controller = ForceRegulationController(hand, obj, estimator, allocator)
    pose_offset = pose_error_offset(spec.pose_error, obj.com)
    n_contacts_gt = _ground_truth_init(backend, controller, pose_offset)
    return TrialSetup(backend, controller, grasp, pose_offset, n_contacts_gt)


def run_trial(
    spec: TrialSpec,
    hand: HandModel | None = None,
    obj: ObjectModel | None = None,
    stop_on_loss: bool = True,
    on_cycle: Callable[[int, HandObjectState, CycleResult], None] | None = None,
) -> RunRecord:
    """Run the perturbation protocol on one stored grasp; the record's meta holds the spec.

    ``on_cycle`` is passed to :func:`~wholehand.loop.scheduler.run_protocol`.
    """
    started = time.perf_counter()
    trial = set_up_trial(spec, hand, obj)
    backend = trial.backend
    protocol = PerturbationProtocol(
        theta_deg=spec.theta_deg, seed=spec.seed, **spec.protocol_params
    )
    record = run_protocol(
        backend, trial.controller, protocol, spec.control_rate, stop_on_loss, on_cycle=on_cycle,
        pose_offset=trial.pose_offset,
    )  # fmt: skip
    record.meta.update(
        {
            "spec": {k: getattr(v, "__name__", v) for k, v in spec.__dict__.items()},
            "grasp_id": trial.grasp.id,
            "n_contacts_gt_init": trial.n_contacts_gt_init,
            "wall_time_s": time.perf_counter() - started,
            "sim_time_s": float(backend.time),
            # MuJoCo's run-time warnings; bad_qacc means it diverged and reset the state.
            "sim_warnings": backend.warnings() if hasattr(backend, "warnings") else {},
        }
    )
    return record


def _ground_truth_init(
    backend: object,
    controller: ForceRegulationController,
    pose_offset: FloatArray | None = None,
) -> int | None:
    """Ground-truth contact count at the initial state (None when the backend has none), and
    the one-off allocation of a non-adaptive baseline on those contacts (paper Sec. IV-A-1).

    With a pose error (``pose_offset``, see :func:`pose_error_offset`) the baseline's contacts
    are expressed in the true object frame and mapped back to the world with the perturbed pose
    ``wMo_true @ pose_offset`` (paper Sec. IV-B-2), as is the centre of mass; the returned count
    is unaffected.
    """
    ground_truth = getattr(backend, "ground_truth_contacts", None)
    allocator = controller.allocator
    if ground_truth is None:
        if isinstance(allocator, FixedAllocationBaseline):
            raise ConfigError(
                f"allocator {type(allocator).__name__} needs ground-truth contacts at "
                f"initialisation; backend {type(backend).__name__} has no ground_truth_contacts()"
            )
        return None
    contacts = ground_truth().to_contact_set(controller.hand)
    if isinstance(allocator, FixedAllocationBaseline):
        state = backend.read_state()  # type: ignore[attr-defined]
        controller.kinematics.update(state.q, state.wMb)
        wMo = state.wMo
        if pose_offset is not None:
            wMo = state.wMo @ pose_offset
            contacts = transform_contacts(contacts, wMo @ np.linalg.inv(state.wMo))
        p_com = wMo[:3, :3] @ controller.obj.com + wMo[:3, 3]
        allocator.initialise(contacts, controller.kinematics, p_com)
    return len(contacts)


def transform_contacts(contacts: ContactSet, M: FloatArray) -> ContactSet:
    """The contact set moved rigidly by the world transform ``M`` (4, 4): points and normals."""
    R, t = M[:3, :3], M[:3, 3]
    return dataclasses.replace(
        contacts, p_world=contacts.p_world @ R.T + t, n_world=contacts.n_world @ R.T
    )


def _allocator_defaults(hand: HandModel) -> dict[str, Any]:
    """Hand-specific allocator parameters: per-joint torque limits and actuated dofs."""
    return {"tau_max": hand.tau_max.copy(), "actuated_dofs": hand.actuated_dofs.copy()}
