"""Actuation-consistency ablation (paper Sec. IV-B-1, Fig. 5).

Two parts, each ``qp`` against ``qp_no_consistency``:

1. ``load_test``: the initial six-direction load test (theta = 0) on the stored power grasps and
   on the three-finger precision grasps (``objects/grasps/<hand>/precision/``), success per grasp
   type.
2. ``net_force``: three-finger precision grasps held without load for ``NET_FORCE_TIME`` s; then
   the measured net contact force on the object, i.e. the sum of MuJoCo's contact forces
   ``ground_truth_contacts().f_world`` [N]. With gravity off and no external load this resultant
   is the object's mass times its acceleration: zero once the realised forces balance. Without
   the constraint the allocation may count on force components the joints cannot produce, and a
   resultant remains while the grasp rearranges. Because a grasp that has settled by 2 s shows
   no resultant either way, each row also has the mean resultant over the window
   (``net_force_mean_N``, one sample per control cycle) and the object's displacement over it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from wholehand.backends.base import HasGroundTruth
from wholehand.errors import ConfigError
from wholehand.grasps.store import stored_grasp_indices
from wholehand.loop.control_loop import ControlLoop, Cycle, Observer
from wholehand.models.object_catalogue import PAPER_OBJECTS
from wholehand.studies.base import (
    DEFAULT_HAND,
    Study,
    TrialJob,
    group_rows,
    protocol_for,
    success_stats,
)
from wholehand.studies.models import model
from wholehand.studies.rows import record_row
from wholehand.trials.trial import TrialSpec, run_trial

if TYPE_CHECKING:
    from wholehand.backends.ground_truth import SimContacts

METHODS = ("qp", "qp_no_consistency")
GRASP_TYPES = ("power", "precision")
"""Grasp styles of the load-test part (paper: Dexonomy types 1 and 7)."""
NET_FORCE_COLUMNS = (
    "method",
    "object",
    "grasp",
    "held",
    "net_force_N",
    "net_force_x",
    "net_force_y",
    "net_force_z",
    "net_force_mean_N",
    "displacement_mm",
    "normal_force_sum_N",
    "n_contacts_gt_end",
    "links_gt_end",
    "error",
)
NET_FORCE_TIME = 2.0
"""When the net force is measured, after initialisation [s] (paper Fig. 5)."""


@dataclass(frozen=True)
class ConsistencyConfig:
    objects: tuple[str, ...]
    grasps: tuple[int, ...] | None
    """Grasp indices per object and type; None: every stored grasp."""
    net_force_objects: tuple[str, ...]
    net_force_grasps: tuple[int, ...] | None
    """Precision grasps whose net force is measured; None: every stored one."""


CONFIGS = {
    "full": ConsistencyConfig(PAPER_OBJECTS, None, PAPER_OBJECTS, None),
    "quick": ConsistencyConfig(PAPER_OBJECTS, (0, 1), ("077_rubiks_cube", "065-f_cups"), (0,)),
    "tiny": ConsistencyConfig(("077_rubiks_cube",), (0,), ("077_rubiks_cube",), (0,)),
}


class NetForceSampler(Observer):
    """The resultant of the simulator's contact forces on the object: every cycle, and at the
    end of the run (after the last step)."""

    def __init__(self) -> None:
        self.resultants: list[float] = []
        self.final: SimContacts | None = None
        self._backend: HasGroundTruth | None = None

    def on_start(self, loop: ControlLoop) -> None:
        if not isinstance(loop.backend, HasGroundTruth):
            raise ConfigError("the net-force measurement needs a backend with ground truth")
        self._backend = loop.backend

    def on_cycle(self, cycle: Cycle) -> str | None:
        assert self._backend is not None
        f = self._backend.ground_truth_contacts().f_world
        self.resultants.append(float(np.linalg.norm(f.sum(0))))
        return None

    def on_end(self, loop: ControlLoop) -> None:
        assert self._backend is not None
        self.final = self._backend.ground_truth_contacts()


def net_force_row(job: TrialJob) -> dict[str, Any]:
    """Hold ``job.spec``'s grasp for ``NET_FORCE_TIME`` without load, then measure the net
    ground-truth contact force on the object (the spec's protocol is replaced by a settle)."""
    spec = dataclasses.replace(
        job.spec,
        theta_deg=0.0,
        protocol_params={"settle_time": NET_FORCE_TIME, "load_duration": 0.0},
    )
    hand, obj = model("hand", spec.hand), model("object", spec.object)
    sampler = NetForceSampler()
    record = run_trial(spec, hand, obj, stop_on_loss=False, observers=[sampler])
    gt = sampler.final
    assert gt is not None
    net = gt.f_world.sum(axis=0)
    row = record_row(record)
    row.update(
        {
            "stages_total": 1,
            "stages_reached": 1,
            "n_contacts_gt_end": len(gt),
            "links_gt_end": " ".join(sorted({hand.link_names[i] for i in gt.link})),
            "net_force_N": round(float(np.linalg.norm(net)), 6),
            "net_force_x": round(float(net[0]), 6),
            "net_force_y": round(float(net[1]), 6),
            "net_force_z": round(float(net[2]), 6),
            "net_force_mean_N": round(float(np.mean(sampler.resultants)), 6),
            "displacement_mm": row["final_displacement_mm"],
            "normal_force_sum_N": round(float(gt.f_normal.sum()), 6),
        }
    )
    row["held"] = bool(record.held_throughout)
    row["failure_stage"] = "" if row["held"] else "settle"
    return row


class ConsistencyStudy(Study):
    name = "consistency"
    description = (
        "qp vs qp_no_consistency: load-test success on power and precision grasps, and the "
        "measured net force on precision grasps (Sec. IV-B-1)"
    )

    def jobs(self, size: str, seed: int, hand: str = DEFAULT_HAND) -> list[TrialJob]:
        cfg = CONFIGS[self.check_size(size)]
        jobs: list[TrialJob] = []
        for style in GRASP_TYPES:
            for obj in cfg.objects:
                for grasp in stored_grasp_indices(hand, obj, style, cfg.grasps):
                    for method in METHODS:
                        spec = TrialSpec(
                            hand=hand,
                            object=obj,
                            grasp=grasp,
                            grasp_type=style,
                            allocator=method,
                            theta_deg=0.0,
                            seed=seed,
                            protocol_params=protocol_for(size),
                        )
                        labels = {"method": method, "part": "load_test"}
                        jobs.append(TrialJob(len(jobs), spec, labels))
        for obj in cfg.net_force_objects:
            for grasp in stored_grasp_indices(hand, obj, "precision", cfg.net_force_grasps):
                for method in METHODS:
                    spec = TrialSpec(
                        hand=hand,
                        object=obj,
                        grasp=grasp,
                        grasp_type="precision",
                        allocator=method,
                        theta_deg=0.0,
                        seed=seed,
                    )
                    labels = {"method": method, "part": "net_force"}
                    jobs.append(TrialJob(len(jobs), spec, labels, "net_force"))
        return jobs

    def summarise(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        load = [r for r in rows if r["part"] == "load_test"]
        success = [
            {"grasp_type": style, "method": m, **success_stats(g)}
            for (style, m), g in group_rows(load, "grasp_type", "method").items()
        ]
        net_rows = [r for r in rows if r["part"] == "net_force" and not r.get("error")]
        net = []
        for (m,), group in group_rows(net_rows, "method").items():
            final = np.array([r["net_force_N"] for r in group], dtype=float)
            mean = np.array([r["net_force_mean_N"] for r in group], dtype=float)
            moved = np.array([r["displacement_mm"] for r in group], dtype=float)
            net.append(
                {
                    "method": m,
                    "n_grasps": len(group),
                    "held": int(sum(bool(r["held"]) for r in group)),
                    "net_force_N_mean": float(final.mean()),
                    "net_force_N_max": float(final.max()),
                    "net_force_window_mean_N": float(mean.mean()),
                    "displacement_mm_mean": float(moved.mean()),
                }
            )
        per_grasp = [
            {k: r.get(k) for k in NET_FORCE_COLUMNS} for r in rows if r["part"] == "net_force"
        ]
        return {
            "load_test": success,
            "net_force": net,
            "net_force_grasps": per_grasp,
            "net_force_time_s": NET_FORCE_TIME,
        }

    def plot(self, rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> None:
        from matplotlib.figure import Figure

        fig = Figure(figsize=(8, 3.2))

        axes = fig.subplots(1, 2)
        s = summary["load_test"]
        styles = sorted({x["grasp_type"] for x in s}, key=GRASP_TYPES.index)
        width = 0.8 / len(METHODS)
        for i, method in enumerate(METHODS):
            cells = {x["grasp_type"]: x for x in s if x["method"] == method}
            xs = [j + (i - 0.5 * (len(METHODS) - 1)) * width for j in range(len(styles))]
            axes[0].bar(
                xs,
                [100 * cells[t]["success"] if t in cells else 0.0 for t in styles],
                width,
                yerr=[100 * cells[t]["se"] if t in cells else 0.0 for t in styles],
                capsize=3,
                label=method,
            )
        axes[0].set_xticks(range(len(styles)), styles)
        axes[0].set_ylabel("load-test success [%]")
        axes[0].set_ylim(0, 105)
        axes[0].legend(fontsize=7)
        n = summary["net_force"]
        bars = np.arange(len(n))
        axes[1].bar(bars - 0.2, [x["net_force_N_mean"] for x in n], 0.4, label="at 2 s")
        axes[1].bar(bars + 0.2, [x["net_force_window_mean_N"] for x in n], 0.4, label="0-2 s mean")
        axes[1].set_xticks(bars, [x["method"] for x in n])
        axes[1].set_ylabel("net contact force, precision [N]")
        axes[1].legend(fontsize=7)
        for ax in axes:
            ax.tick_params(axis="x", labelsize=8)
        fig.tight_layout()
        fig.savefig(path, dpi=120)
