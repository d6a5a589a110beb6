"""The scheduler: estimator -> allocator -> backend at a control rate over a finer sim step."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.backends.base import HandObjectState, PerturbableBackend
from wholehand.errors import ConfigError
from wholehand.loop.controller import CycleResult, ForceRegulationController
from wholehand.loop.grasp_loss import GraspLossCheck
from wholehand.loop.protocol import PerturbationProtocol
from wholehand.loop.record import STATUS_CODES, RunRecord

CONTROL_RATE = 200.0
"""Default control rate in simulation time [Hz]; the simulation steps finer in between."""


def run_protocol(
    backend: PerturbableBackend,
    controller: ForceRegulationController,
    protocol: PerturbationProtocol,
    control_rate: float = CONTROL_RATE,
    stop_on_loss: bool = True,
    on_cycle: Callable[[int, HandObjectState, CycleResult], None] | None = None,
    pose_offset: npt.NDArray[np.float64] | None = None,
) -> RunRecord:
    """Run the perturbation protocol from the backend's current state; one record row per cycle.

    Each cycle reads the state, checks the grasp-loss criterion, runs the controller, applies
    its torques and the stage's external wrench, and advances the backend by 1/control_rate.
    ``on_cycle(cycle_index, state, cycle_result)``, if given, is called after each row is
    recorded (e.g. to update a live viewer). ``pose_offset`` (4, 4), if given, is a constant
    object-frame error: the controller gets ``state.wMo @ pose_offset`` every cycle, while the
    simulation, the grasp-loss check and the record keep the true pose.
    """
    if not control_rate > 0.0:
        raise ConfigError(f"run_protocol: control_rate must be > 0 [Hz], got {control_rate!r}")
    if not isinstance(backend, PerturbableBackend):
        raise ConfigError(
            f"run_protocol needs a backend that can push the object (PerturbableBackend); "
            f"{type(backend).__name__} cannot"
        )
    dt = 1.0 / control_rate
    obj = controller.obj
    loss = GraspLossCheck(controller.hand, obj)
    stages = protocol.stages()
    record = RunRecord(
        meta={"control_rate": control_rate, "theta_deg": protocol.theta_deg, "seed": protocol.seed},
        stages=[s.name for s in stages],
    )
    wMo0 = backend.read_state().wMo.copy()
    no_torque = np.zeros(3)
    try:
        for index, stage in enumerate(stages):
            if stage.kind == "rotate":
                backend.set_object_spring(*protocol.spring(obj.mass, obj.inertia, obj.com, wMo0))
            force = protocol.load_force(stage, obj.mass)
            for _ in range(int(round(stage.duration * control_rate))):
                state = backend.read_state()
                wMo = None if pose_offset is None else state.wMo @ pose_offset
                cycle = controller.step(state, wMo)
                held = loss.held(controller.kinematics, state.wMo)
                allocation = cycle.allocation
                backend.apply_torques(allocation.tau)
                backend.apply_object_wrench(force, no_torque)
                record.append(
                    t=state.stamp_q,
                    stage=index,
                    n_contacts=len(cycle.contacts),
                    residual_wrench=allocation.residual_wrench,
                    tau=allocation.tau,
                    qp_time=allocation.solve_time,
                    estimate_time=cycle.estimate_time,
                    cycle_time=cycle.cycle_time,
                    status=STATUS_CODES[allocation.status],
                    held=held,
                    p_object=state.wMo[:3, 3].copy(),
                    r_object=pin.log3(state.wMo[:3, :3]),
                    q=state.q.copy(),
                    contact_p=cycle.contacts.p_world,
                    contact_n=cycle.contacts.n_world,
                    contact_f=allocation.f_world,
                    contact_link=cycle.contacts.link,
                )
                if on_cycle is not None:
                    on_cycle(len(record.rows["t"]) - 1, state, cycle)
                if not held and stop_on_loss:
                    return record
                backend.step(dt)
            if stage.kind == "rotate":
                backend.set_object_spring(None)
    finally:
        backend.set_object_spring(None)
        backend.apply_object_wrench(np.zeros(3), np.zeros(3))
    return record
