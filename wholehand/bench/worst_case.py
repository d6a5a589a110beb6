"""``wholehand bench cycle --worst``: the control step on the states of grasps being lost.

The worst cycles come just before a loss: contacts change, torque rows bind, screening needs
rounds. This benchmark first runs perturbation trials where the paper's method loses grasps
(by default grasps 0 and 1 of the mustard bottle and the extra-large clamp, pulled by 90 deg:
the bottle's two are lost), keeps those that were lost, and then replays every recorded state
of them, up to the loss, through a fresh force-regulation stage: the same contacts, Jacobians
and QPs as the loop, without the simulation, so the times are comparable from one code version
to the next (same seeds, same states).

Per stage it reports p50/p99/p99.9/max: ``estimate`` (kinematics and contact estimation),
``qp`` (building and solving the allocation QP, all screening rounds), split into
``qp_solver`` (inside the QP solver's calls) and ``qp_other`` (building the problems and the
allocator's own work, Python mostly), ``rest`` (Jacobians, normal checks, the torque) and
``step`` (the whole stage), how many QPs took longer than ``deadline`` (the allocator's
deadline would have stopped them), the most cycles in a row that gave no torque (the loop
would have held the last feasible one: ``longest_hold_cycles``), and in how many cycles the
estimator's selected samples changed (``selection_changes``: cycles whose contacts jumped, which
moves the consistency rows and costs the QP its warm start; estimators that say which samples
they selected, as ``mesh_sdf`` does). ``estimator_params`` apply to the replay only, so that
two settings are compared on the same states.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Sequence
from typing import Any

import numpy as np
import pinocchio as pin

from wholehand import registry
from wholehand.backends.observation import JointHistory, Observation
from wholehand.loop.record import RunRecord
from wholehand.loop.regulation import ForceRegulation
from wholehand.loop.stage import CycleContext
from wholehand.models.hand import HandModel, load_hand
from wholehand.models.kinematics import HandKinematics
from wholehand.models.object_catalogue import load_object
from wholehand.models.objects import ObjectModel
from wholehand.provenance import provenance
from wholehand.timing import percentiles_us
from wholehand.trials.trial import TrialSpec, load_allocator, run_trial

WORST_OBJECTS = ("006_mustard_bottle", "052_extra_large_clamp")
"""Where the paper's method loses most grasps in the perturbation study (theta 90 deg)."""

QP_DEADLINE = 1e-3
"""The issue's bound on one QP solve [s]."""


def _pose(p: np.ndarray, r: np.ndarray) -> np.ndarray:
    M = np.eye(4)
    M[:3, :3] = pin.exp3(r)
    M[:3, 3] = p
    return M


def record_poses(record: RunRecord) -> tuple[np.ndarray, np.ndarray]:
    """(rows, 4, 4) hand-base and object poses in the world of every row of ``record``."""
    a = record.arrays()
    rows = a["q"].shape[0]
    wMb = np.array([_pose(a["p_base"][i], a["r_base"][i]) for i in range(rows)])
    wMo = np.array([_pose(a["p_object"][i], a["r_object"][i]) for i in range(rows)])
    return wMb.reshape(rows, 4, 4), wMo.reshape(rows, 4, 4)


def replay(
    record: RunRecord, hand: HandModel, obj: ObjectModel, stage: ForceRegulation
) -> tuple[dict[str, np.ndarray], Counter[str]]:
    """Run ``stage`` on every recorded state of ``record`` (true q and object pose), timing each
    step; returns per-cycle durations [ns] of ``step``, ``estimate``, ``qp`` and ``qp_solver``
    (:attr:`~wholehand.allocation.base.Allocation.solver_time`) and the
    commanded torques ``tau`` (rows, n_v) [N*m] (NaN where the stage gave none), and the
    stage's statuses; ``changed`` (rows,) says where the estimator's selected samples differ
    from the cycle before."""
    a = record.arrays()
    rows = a["q"].shape[0]
    poses_b, poses_o = record_poses(record)
    history = JointHistory(hand.nq, 4)
    now, then = HandKinematics(hand), HandKinematics(hand)
    out = {key: np.zeros(rows, dtype=np.int64) for key in ("step", "estimate", "qp", "qp_solver")}
    statuses: Counter[str] = Counter()
    taus = np.full((rows, hand.nv), np.nan)
    changed = np.zeros(rows, dtype=bool)
    previous: set[int] | None = None
    dt = 1.0 / float(record.meta.get("control_rate", 200.0))
    for i in range(rows):
        q = a["q"][i]
        wMb, wMo = poses_b[i], poses_o[i]
        t = float(a["t"][i])
        history.push(t, q, wMb)
        obs = Observation(q, np.zeros(hand.nv), wMb, t, wMo, t, history)
        context = CycleContext(t, dt, obs, hand, obj, now, then)
        started = time.perf_counter_ns()
        output = stage.step(context)
        out["step"][i] = time.perf_counter_ns() - started
        out["estimate"][i] = int(output.estimate_time * 1e9)
        allocation = output.allocation
        if allocation is not None:
            out["qp"][i] = int(allocation.solve_time * 1e9)
            out["qp_solver"][i] = int(allocation.solver_time * 1e9)
        statuses[output.status] += 1
        if output.command is not None:
            taus[i] = output.command.tau
        selected = getattr(stage.estimator, "rows", None)
        if selected is not None:
            now_rows = set(selected.tolist())
            changed[i] = previous is not None and now_rows != previous
            previous = now_rows
    return {**out, "tau": taus, "changed": changed}, statuses


def longest_run(flags: np.ndarray) -> int:
    """The most consecutive True values in the (n,) boolean ``flags``."""
    edges = np.flatnonzero(np.diff(np.r_[0, flags.astype(np.int8), 0]))
    return int((edges[1::2] - edges[::2]).max(initial=0))


def run_worst_case_benchmark(
    hand: str = "allegro_right",
    objects: Sequence[str] = WORST_OBJECTS,
    grasps: Sequence[int] = (0, 1),
    theta_deg: float = 90.0,
    estimator: str = "mesh_sdf",
    allocator: str = "qp",
    allocator_params: dict[str, Any] | None = None,
    deadline: float = QP_DEADLINE,
    estimator_params: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Run the trials, keep the lost ones, replay their states (module docstring)."""
    hand_model = load_hand(hand)
    times: dict[str, list[np.ndarray]] = {"step": [], "estimate": [], "qp": [], "qp_solver": []}
    lost = []
    statuses: Counter[str] = Counter()
    longest_hold = 0
    changes = 0
    for name in objects:
        obj = load_object(name)
        for g in grasps:
            spec = TrialSpec(
                hand=hand,
                object=name,
                grasp=g,
                theta_deg=theta_deg,
                estimator=estimator,
                allocator=allocator,
            )
            record = run_trial(spec, hand_model, obj, stop_on_loss=True)
            if record.held_throughout:
                continue
            lost.append({"object": name, "grasp": g, "cycles": len(record.rows["t"])})
            est = registry.load(
                "contact_estimators",
                estimator,
                hand=hand_model,
                obj=obj,
                **dict(estimator_params or {}),
            )
            alloc = load_allocator(allocator, hand_model, dict(allocator_params or {}))
            stage = ForceRegulation(hand_model, obj, est, alloc)
            durations, seen = replay(record, hand_model, obj, stage)
            statuses.update(seen)
            longest_hold = max(longest_hold, longest_run(np.isnan(durations["tau"][:, 0])))
            changes += int(durations["changed"].sum())
            for key in times:
                times[key].append(durations[key])
    if not lost:
        return {"benchmark": "cycle-worst", "lost_trials": [], "note": "no trial was lost"}
    cat = {key: np.concatenate(v) for key, v in times.items()}
    rest = np.maximum(cat["step"] - cat["estimate"] - cat["qp"], 0)
    return {
        "benchmark": "cycle-worst",
        "hand": hand,
        "theta_deg": theta_deg,
        "estimator": estimator,
        "allocator": allocator,
        "allocator_params": allocator_params or {},
        "estimator_params": estimator_params or {},
        "lost_trials": lost,
        "cycles": int(cat["step"].size),
        "stages": {
            "step": percentiles_us(cat["step"]),
            "estimate": percentiles_us(cat["estimate"]),
            "qp": percentiles_us(cat["qp"]),
            "qp_solver": percentiles_us(cat["qp_solver"]),
            "qp_other": percentiles_us(cat["qp"] - cat["qp_solver"]),
            "rest": percentiles_us(rest),
        },
        "statuses": dict(statuses),
        "qp_over_deadline": int((cat["qp"] > deadline * 1e9).sum()),
        "longest_hold_cycles": longest_hold,
        "selection_changes": changes,
        "deadline_ms": deadline * 1e3,
        "machine": provenance(),
    }
