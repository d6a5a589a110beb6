"""One perturbation trial of a stored grasp: build the scene, the controller, run the protocol."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from wholehand import registry
from wholehand.allocation.baselines import FixedAllocationBaseline
from wholehand.backends.base import HandObjectState
from wholehand.errors import ConfigError
from wholehand.grasps.store import load_grasps
from wholehand.loop.controller import CycleResult, ForceRegulationController
from wholehand.loop.protocol import PerturbationProtocol
from wholehand.loop.record import RunRecord
from wholehand.loop.scheduler import CONTROL_RATE, run_protocol
from wholehand.models.hand import HandModel, load_hand
from wholehand.models.objects import ObjectModel, load_object


@dataclass(frozen=True)
class TrialSpec:
    """Everything that defines one trial; equal specs give equal records."""

    hand: str = "allegro_right"
    object: str = "077_rubiks_cube"
    grasp: int = 0
    estimator: str = "mesh_sdf"
    allocator: str = "qp"
    theta_deg: float = 60.0
    seed: int = 0
    control_rate: float = CONTROL_RATE
    gravity: bool = False
    backend: str = "mujoco"
    estimator_params: dict[str, Any] = field(default_factory=dict)
    allocator_params: dict[str, Any] = field(default_factory=dict)
    protocol_params: dict[str, Any] = field(default_factory=dict)
    """Overrides of :class:`PerturbationProtocol` fields (e.g. shorter stages for tests)."""


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
    hand = hand or load_hand(spec.hand)
    obj = obj or load_object(spec.object)
    grasps = load_grasps(spec.hand, spec.object)
    grasp = grasps[spec.grasp % len(grasps)]
    backend = registry.load(
        "backends",
        spec.backend,
        hand=hand,
        obj=obj,
        q_init=grasp.q_array(hand),
        wMo_init=grasp.object_pose(hand.wMb),
        gravity=spec.gravity,
    )
    estimator = registry.load(
        "contact_estimators", spec.estimator, hand=hand, obj=obj, **spec.estimator_params
    )
    allocator_params = {**_allocator_defaults(hand), **spec.allocator_params}
    allocator = registry.load("allocators", spec.allocator, **allocator_params)
    controller = ForceRegulationController(hand, obj, estimator, allocator)
    n_contacts_gt = _ground_truth_init(backend, controller)
    protocol = PerturbationProtocol(
        theta_deg=spec.theta_deg, seed=spec.seed, **spec.protocol_params
    )
    record = run_protocol(
        backend, controller, protocol, spec.control_rate, stop_on_loss, on_cycle=on_cycle
    )
    record.meta.update(
        {
            "spec": {k: getattr(v, "__name__", v) for k, v in spec.__dict__.items()},
            "grasp_id": grasp.id,
            "n_contacts_gt_init": n_contacts_gt,
            "wall_time_s": time.perf_counter() - started,
            "sim_time_s": float(backend.time),
        }
    )
    return record


def _ground_truth_init(backend: object, controller: ForceRegulationController) -> int | None:
    """Ground-truth contact count at the initial state (None when the backend has none), and
    the one-off allocation of a non-adaptive baseline on those contacts (paper Sec. IV-A-1)."""
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
        p_com = state.wMo[:3, :3] @ controller.obj.com + state.wMo[:3, 3]
        allocator.initialise(contacts, controller.kinematics, p_com)
    return len(contacts)


def _allocator_defaults(hand: HandModel) -> dict[str, Any]:
    """Hand-specific allocator parameters: per-joint torque limits and actuated dofs."""
    return {"tau_max": hand.tau_max.copy(), "actuated_dofs": hand.actuated_dofs.copy()}
