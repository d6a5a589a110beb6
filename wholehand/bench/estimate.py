"""``wholehand bench contacts --recorded``: the estimation part of a control step, on the loop's
own states, phase by phase.

``bench contacts`` times the estimator on seeded grasp-like states; inside the loop the same
work sees other states (a held grasp: many links near the surface) and comes with kinematics
and Jacobians around it. This benchmark first runs one trial of a stored grasp through the
perturbation protocol, then replays every recorded state (true joint angles and object pose)
and times the phases of :meth:`~wholehand.loop.regulation.ForceRegulation.step` before the QP,
each with ``perf_counter_ns``:

- ``kinematics``: forward kinematics of the hand at q (``HandKinematics.update``);
- ``estimate``: the estimator's ``estimate()`` (for ``mesh_sdf``: one compiled kernel that culls
  link clusters, looks the samples up in the SDF, keeps the closest K per link and takes the
  gradients there);
- ``jacobians``: the point Jacobians of the kept contacts (``actuation_jacobians``).

The estimate is made at the current q here (``estimate_at="current"``), so no contacts are moved
between joint configurations.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from wholehand import registry
from wholehand.bench.worst_case import record_poses
from wholehand.models.hand import load_hand
from wholehand.models.kinematics import HandKinematics
from wholehand.models.object_catalogue import load_object
from wholehand.provenance import provenance
from wholehand.timing import percentiles_us
from wholehand.trials.trial import TrialSpec, run_trial

PHASES = ("kinematics", "estimate", "jacobians")
"""Timed phases, in the order of a control step."""


def run_recorded_contact_benchmark(
    hand: str = "allegro_right",
    obj: str = "077_rubiks_cube",
    grasp: int = 0,
    theta_deg: float = 60.0,
    estimator: str = "mesh_sdf",
    estimator_params: dict[str, Any] | None = None,
    protocol_params: dict[str, Any] | None = None,
    repeats: int = 3,
) -> dict[str, Any]:
    """Run the trial, replay its states ``repeats`` times; p50/p95/p99 per phase (module
    docstring), kept contacts and the trial's outcome (JSON-able)."""
    hand_model, obj_model = load_hand(hand), load_object(obj)
    params = dict(estimator_params or {})
    spec = TrialSpec(
        hand=hand,
        object=obj,
        grasp=grasp,
        theta_deg=theta_deg,
        estimator=estimator,
        estimator_params=params,
        protocol_params=dict(protocol_params or {}),
    )
    record = run_trial(spec, hand_model, obj_model)
    a = record.arrays()
    wMb, wMo = record_poses(record)
    est = registry.load("contact_estimators", estimator, hand=hand_model, obj=obj_model, **params)
    kin = HandKinematics(hand_model)
    rows = a["q"].shape[0]
    times = {phase: np.zeros(rows * repeats, dtype=np.int64) for phase in PHASES}
    kept = np.zeros(rows, dtype=np.int64)
    kin.update(a["q"][0], wMb[0])
    est.estimate(kin, wMo[0])  # compile before timing
    for r in range(repeats):
        for i in range(rows):
            k = r * rows + i
            t0 = time.perf_counter_ns()
            kin.update(a["q"][i], wMb[i])
            t1 = time.perf_counter_ns()
            contacts = est.estimate(kin, wMo[i])
            t2 = time.perf_counter_ns()
            kin.actuation_jacobians(hand_model.link_joint[contacts.link], contacts.p_world)
            t3 = time.perf_counter_ns()
            times["kinematics"][k], times["estimate"][k], times["jacobians"][k] = (
                t1 - t0,
                t2 - t1,
                t3 - t2,
            )
            kept[i] = len(contacts)
    total = times["kinematics"] + times["estimate"] + times["jacobians"]
    return {
        "benchmark": "contacts-recorded",
        "hand": hand_model.name,
        "object": obj_model.name,
        "grasp": grasp,
        "theta_deg": theta_deg,
        "estimator": estimator,
        "params": params,
        "held": bool(record.held_throughout),
        "states": rows,
        "repeats": repeats,
        "kept_contacts_mean": round(float(kept.mean()), 2),
        "kept_contacts_max": int(kept.max()),
        "phases": {phase: percentiles_us(times[phase]) for phase in PHASES},
        "total": percentiles_us(total),
        "machine": provenance(),
    }


__all__ = ["PHASES", "run_recorded_contact_benchmark"]
