"""Actuation-consistency ablation (paper Sec. IV-B-1, Fig. 5).

Two parts. (1) ``qp`` versus ``qp_no_consistency`` under the initial six-direction load test
(theta = 0) on the shipped grasps (all power grasps: the paper's three-finger precision grasps are
not shipped). (2) The measured net contact force on the object 2 s after initialisation on a
three-finger grasp (077_rubiks_cube grasp 4: middle, ring and thumb, plus the palm), both ways:
the sum of the MuJoCo contact forces ``ground_truth_contacts().f_world``. Without the constraint
the allocation counts on force components the joints cannot produce, and a resultant remains.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from wholehand.loop.trial import TrialSpec
from wholehand.models.objects import PAPER_OBJECTS
from wholehand.studies.base import (
    Study,
    TrialJob,
    group_rows,
    protocol_for,
    success_stats,
)

METHODS = ("qp", "qp_no_consistency")
NET_FORCE_COLUMNS = (
    "method", "object", "grasp", "held", "net_force_N", "net_force_x", "net_force_y",
    "net_force_z", "normal_force_sum_N", "n_contacts_gt_end", "links_gt_end", "error",
)  # fmt: skip
NET_FORCE_OBJECT = "077_rubiks_cube"
NET_FORCE_GRASP = 4
"""A three-finger grasp of the shipped set: middle, ring and thumb (and the palm) touch."""
NET_FORCE_TIME = 2.0
"""When the net force is measured, after initialisation [s] (paper Fig. 5)."""


@dataclass(frozen=True)
class ConsistencyConfig:
    objects: tuple[str, ...]
    grasps: tuple[int, ...]


CONFIGS = {
    "full": ConsistencyConfig(PAPER_OBJECTS, tuple(range(10))),
    "quick": ConsistencyConfig(PAPER_OBJECTS, (0, 1)),
    "tiny": ConsistencyConfig(("077_rubiks_cube",), (0,)),
}


def net_force_row(job: TrialJob) -> dict[str, Any]:
    """Hold ``job.spec``'s grasp for ``NET_FORCE_TIME`` without load, then measure the net
    ground-truth contact force on the object (the spec's protocol is replaced by a settle)."""
    from wholehand.loop.protocol import PerturbationProtocol
    from wholehand.loop.scheduler import run_protocol
    from wholehand.loop.trial import set_up_trial
    from wholehand.studies.runner import _model, record_row

    spec = job.spec
    hand, obj = _model("hand", spec.hand), _model("object", spec.object)
    trial = set_up_trial(spec, hand, obj)
    backend = trial.backend
    protocol = PerturbationProtocol(theta_deg=0.0, settle_time=NET_FORCE_TIME, load_duration=0.0)
    record = run_protocol(
        backend, trial.controller, protocol, spec.control_rate, stop_on_loss=False
    )
    gt = backend.ground_truth_contacts()
    net = gt.f_world.sum(axis=0)
    row = record_row(record)
    row.update({
        "stages_total": 1, "stages_reached": 1,
        "n_contacts_gt_end": len(gt),
        "links_gt_end": " ".join(sorted({hand.link_names[i] for i in gt.link})),
        "net_force_N": round(float(np.linalg.norm(net)), 6),
        "net_force_x": round(float(net[0]), 6), "net_force_y": round(float(net[1]), 6),
        "net_force_z": round(float(net[2]), 6),
        "normal_force_sum_N": round(float(gt.f_normal.sum()), 6),
    })  # fmt: skip
    row["held"] = bool(record.held_throughout)
    row["failure_stage"] = "" if row["held"] else "settle"
    return row


class ConsistencyStudy(Study):
    name = "consistency"
    description = "qp vs qp_no_consistency: load-test success and measured net force (Sec. IV-B-1)"

    def jobs(self, size: str, seed: int) -> list[TrialJob]:
        cfg = CONFIGS[self.check_size(size)]
        jobs: list[TrialJob] = []
        for obj in cfg.objects:
            for grasp in cfg.grasps:
                for method in METHODS:
                    spec = TrialSpec(
                        object=obj, grasp=grasp, allocator=method, theta_deg=0.0, seed=seed,
                        protocol_params=protocol_for(size),
                    )  # fmt: skip
                    jobs.append(TrialJob(len(jobs), spec, {"method": method, "part": "load_test"}))
        for method in METHODS:
            spec = TrialSpec(object=NET_FORCE_OBJECT, grasp=NET_FORCE_GRASP, allocator=method,
                             theta_deg=0.0, seed=seed)  # fmt: skip
            jobs.append(
                TrialJob(len(jobs), spec, {"method": method, "part": "net_force"}, "net_force")
            )
        return jobs

    def summarise(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        load = [r for r in rows if r["part"] == "load_test"]
        success = [
            {"method": m, **success_stats(g)} for (m,), g in group_rows(load, "method").items()
        ]
        net = [{k: r.get(k) for k in NET_FORCE_COLUMNS} for r in rows if r["part"] == "net_force"]
        return {"load_test": success, "net_force": net, "net_force_time_s": NET_FORCE_TIME}

    def plot(self, rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> None:
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 2, figsize=(7, 3))
        s = summary["load_test"]
        axes[0].bar([x["method"] for x in s], [100 * x["success"] for x in s],
                    yerr=[100 * x["se"] for x in s], capsize=4)  # fmt: skip
        axes[0].set_ylabel("load-test success [%]")
        axes[0].set_ylim(0, 105)
        n = summary["net_force"]
        axes[1].bar([x["method"] for x in n], [x["net_force_N"] or 0.0 for x in n])
        axes[1].set_ylabel(f"net contact force at {NET_FORCE_TIME:g} s [N]")
        for ax in axes:
            ax.tick_params(axis="x", labelsize=8)
        fig.tight_layout()
        fig.savefig(path, dpi=120)
        plt.close(fig)
