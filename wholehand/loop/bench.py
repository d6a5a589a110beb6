"""``wholehand bench cycle``: full control-step latency during held grasps, per K."""

from __future__ import annotations

import platform

import numpy as np

from wholehand.loop.trial import TrialSpec, run_trial
from wholehand.models.hand import load_hand
from wholehand.models.object_catalogue import load_object
from wholehand.timing import percentiles_us


def run_cycle_benchmark(
    hand: str = "allegro_right",
    obj: str = "077_rubiks_cube",
    ks: tuple[int, ...] = (1, 3, 5, 7),
    grasps: tuple[int, ...] = (0, 1),
    estimator: str = "mesh_sdf",
    allocator: str = "qp",
) -> dict[str, object]:
    """Latency of state -> contacts -> Jacobians -> QP -> torque (simulation excluded).

    Each K runs the settle and six-direction load stages of the protocol (6.5 s of simulation,
    1300 cycles at 200 Hz) on each listed grasp; every cycle is timed.
    """
    hand_model, obj_model = load_hand(hand), load_object(obj)
    rows = []
    for k in ks:
        times, contacts, qp, est, held = [], [], [], [], []
        for g in grasps:
            spec = TrialSpec(
                hand=hand,
                object=obj,
                grasp=g,
                estimator=estimator,
                allocator=allocator,
                theta_deg=0.0,
                estimator_params={"k": k},
            )
            record = run_trial(spec, hand_model, obj_model, stop_on_loss=False)
            a = record.arrays()
            times.append(a["cycle_time"])
            contacts.append(a["n_contacts"])
            qp.append(a["qp_time"])
            est.append(a["estimate_time"])
            held.append(record.held_throughout)
        cycle_ns = np.concatenate(times) * 1e9
        rows.append(
            {
                "k": k,
                "cycle": percentiles_us(cycle_ns),
                "qp": percentiles_us(np.concatenate(qp) * 1e9),
                "estimate": percentiles_us(np.concatenate(est) * 1e9),
                "mean_qp_contacts": round(float(np.concatenate(contacts).mean()), 1),
                "achievable_rate_hz": round(float(1e9 / cycle_ns.mean()), 1),
                "grasps_held": int(sum(held)),
            }
        )
    return {
        "benchmark": "cycle",
        "hand": hand_model.name,
        "object": obj_model.name,
        "estimator": estimator,
        "allocator": allocator,
        "grasps": list(grasps),
        "results": rows,
        "machine": {"python": platform.python_version(), "cpu": platform.machine()},
    }
