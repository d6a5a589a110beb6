"""``wholehand bench cycle``: full control-step latency during held grasps, per K."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from wholehand.models.hand import load_hand
from wholehand.models.object_catalogue import load_object
from wholehand.provenance import provenance
from wholehand.timing import percentiles_us
from wholehand.trials.trial import TrialSpec, run_trial


def run_cycle_benchmark(
    hand: str = "allegro_right",
    objects: Sequence[str] = ("077_rubiks_cube",),
    ks: tuple[int, ...] = (1, 3, 5, 7),
    grasps: tuple[int, ...] = (0, 1),
    estimator: str = "mesh_sdf",
    allocator: str = "qp",
    theta_deg: float = 0.0,
    protocol_params: dict[str, float] | None = None,
    allocator_params: dict[str, object] | None = None,
) -> dict[str, object]:
    """Latency of state -> contacts -> Jacobians -> QP -> torque (simulation excluded).

    Each K runs the perturbation protocol on each listed grasp of each object: the settle and
    the six-direction load test (6.5 s of simulation, 1300 cycles at 200 Hz), and with
    ``theta_deg`` > 0 [deg] the pull about the trial's seeded axis and the load test again
    (14 s, 2800 cycles), until the grasp is lost: the cycles before a loss, where the
    allocation is hardest, are in, those of an object falling away are not. Every cycle is
    timed; the percentiles pool all trials of a K. ``held_commands`` counts the cycles that kept
    the last feasible torque (an allocation past its deadline, say), ``longest_hold_cycles``
    the most of them in a row in one trial. ``protocol_params``: the protocol's
    parameters (:class:`~wholehand.trials.protocol.PerturbationProtocol`; None: the paper's);
    ``allocator_params``: the allocator's keyword arguments (e.g. ``{"options": {"deadline":
    0.002, "screen_edges": True}}``).
    """
    hand_model = load_hand(hand)
    models = {name: load_object(name) for name in objects}
    rows = []
    for k in ks:
        times, contacts, qp, est, held = [], [], [], [], []
        held_commands = longest_hold = 0
        for name, obj_model in models.items():
            for g in grasps:
                spec = TrialSpec(
                    hand=hand,
                    object=name,
                    grasp=g,
                    estimator=estimator,
                    allocator=allocator,
                    theta_deg=theta_deg,
                    estimator_params={"k": k},
                    protocol_params=dict(protocol_params or {}),
                    allocator_params=dict(allocator_params or {}),
                )
                record = run_trial(spec, hand_model, obj_model, stop_on_loss=True)
                a = record.arrays()
                times.append(a["cycle_time"])
                contacts.append(a["n_contacts"])
                qp.append(a["qp_time"])
                est.append(a["estimate_time"])
                held.append(record.held_throughout)
                report = record.meta["loop"]
                held_commands += report["held_commands"]
                longest_hold = max(longest_hold, report["longest_hold"])
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
                "trials": len(held),
                "held_commands": held_commands,
                "longest_hold_cycles": longest_hold,
            }
        )
    return {
        "benchmark": "cycle",
        "hand": hand_model.name,
        "objects": [m.name for m in models.values()],
        "theta_deg": theta_deg,
        "estimator": estimator,
        "allocator": allocator,
        "allocator_params": dict(allocator_params or {}),
        "grasps": list(grasps),
        "results": rows,
        "machine": provenance(),
    }
