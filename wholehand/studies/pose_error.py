"""Pose-error study (paper Sec. IV-B-2, Fig. 6): success vs a constant object-pose error.

The object pose given to the controller carries a constant error ``wMo_true @ T``: a rotation
by ``rot_deg`` about a random axis through the object's centre of mass and a translation by
``trans_mm`` along a random direction, both in the object frame (``TrialSpec.pose_error``,
:func:`~wholehand.trials.trial.pose_error_offset`). The simulation and the grasp-loss check keep
the true pose. Methods: ``qp`` at three contact thresholds ``d_thresh`` (0.5, 1, 2 cm) and the
``feedforward`` baseline, whose one-off allocation uses ground-truth contacts mapped to the world
with the perturbed pose. Only the six-direction load test runs (theta = 0). Per grasp and level
> 0, ``repeats`` random offset directions; the directions depend on (object, grasp, repeat) only,
so all methods and levels share them (levels differ in magnitude). Level (0, 0) runs once.
Success is the mean of grasp-level success rates, +- 1 standard error across grasps.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wholehand.grasps.store import stored_grasp_indices
from wholehand.models.object_catalogue import PAPER_OBJECTS
from wholehand.studies.base import (
    DEFAULT_HAND,
    Study,
    TrialJob,
    derive_seed,
    group_rows,
    protocol_for,
    save_success_figure,
    success_stats,
    trials_label,
)
from wholehand.trials.trial import TrialSpec

LEVELS: tuple[tuple[float, float], ...] = ((0.0, 0.0), (10.0, 5 / 3), (20.0, 10 / 3), (30.0, 5.0))
"""(rot_deg, trans_mm) pose-error levels: 0-30 deg and 0-5 mm in equal steps (paper)."""
D_THRESHOLDS: tuple[float, ...] = (0.005, 0.01, 0.02)
"""Contact thresholds of ``qp`` [m] (paper: 0.5, 1 and 2 cm)."""


@dataclass(frozen=True)
class PoseErrorConfig:
    """Design of one size of the pose-error study."""

    objects: tuple[str, ...]
    grasps: tuple[int, ...]
    levels: tuple[tuple[float, float], ...]
    repeats: int
    """Random offset directions per grasp at each level > 0 (level (0, 0) runs once)."""
    d_thresholds: tuple[float, ...] = D_THRESHOLDS
    feedforward: bool = True


CONFIGS = {
    "full": PoseErrorConfig(PAPER_OBJECTS, tuple(range(10)), LEVELS, 5),
    "quick": PoseErrorConfig(("077_rubiks_cube", "065-f_cups"), (0, 1), LEVELS, 2),
    "tiny": PoseErrorConfig(("077_rubiks_cube",), (0,), (LEVELS[0], LEVELS[-1]), 1, (0.01,)),
}


def method_name(method: str, d_thresh: float | None) -> str:
    """Legend name of a (method, d_thresh) variant, e.g. ``"qp d=1 cm"``."""
    return method if d_thresh is None else f"{method} d={100 * d_thresh:g} cm"


class PoseErrorStudy(Study):
    name = "pose-error"
    description = "success vs constant object-pose error, qp per d_thresh vs feedforward (Fig. 6)"

    def jobs(self, size: str, seed: int, hand: str = DEFAULT_HAND) -> list[TrialJob]:
        cfg = CONFIGS[self.check_size(size)]
        protocol = protocol_for(size)
        variants: list[tuple[str, float | None]] = [("qp", d) for d in cfg.d_thresholds]
        if cfg.feedforward:
            variants.append(("feedforward", None))
        jobs: list[TrialJob] = []
        for oi, obj in enumerate(cfg.objects):
            for grasp in stored_grasp_indices(hand, obj, "power", cfg.grasps):
                for rot, trans in cfg.levels:
                    zero = rot == 0.0 and trans == 0.0
                    for repeat in range(1 if zero else cfg.repeats):
                        offset_seed = derive_seed(seed, oi, grasp, repeat)
                        pose_error = (
                            {}
                            if zero
                            else {
                                "rot_deg": rot,
                                "trans_mm": trans,
                                "seed": offset_seed,
                            }
                        )
                        for method, d_thresh in variants:
                            spec = TrialSpec(
                                hand=hand,
                                object=obj,
                                grasp=grasp,
                                allocator=method,
                                theta_deg=0.0,
                                seed=offset_seed,
                                protocol_params=protocol,
                                estimator_params={} if d_thresh is None else {"d_thresh": d_thresh},
                                pose_error=pose_error,
                            )
                            labels = {
                                "method": method,
                                "d_thresh": d_thresh,
                                "rot_deg": rot,
                                "trans_mm": round(trans, 6),
                                "repeat": repeat,
                            }
                            jobs.append(TrialJob(len(jobs), spec, labels))
        return jobs

    def summarise(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        groups = []
        keys = ("method", "d_thresh", "rot_deg", "trans_mm")
        for (method, d_thresh, rot, trans), group in group_rows(rows, *keys).items():
            groups.append(
                {
                    "method": method,
                    "d_thresh": d_thresh,
                    "rot_deg": rot,
                    "trans_mm": trans,
                    **success_stats(group),
                }
            )
        failures: dict[str, dict[str, int]] = {}
        for r in rows:
            if not r["held"]:
                where = failures.setdefault(method_name(r["method"], r["d_thresh"]), {})
                stage = str(r.get("failure_stage", ""))
                where[stage] = where.get(stage, 0) + 1
        return {"groups": groups, "failure_stages": failures}

    def plot(self, rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> None:
        import numpy as np
        from matplotlib.figure import Figure

        fig = Figure(figsize=(5.5, 3.5))

        ax = fig.subplots()
        by_variant = group_rows(summary["groups"], "method", "d_thresh")
        ticks: dict[float, str] = {}
        for (method, d_thresh), groups in by_variant.items():
            rot = np.array([g["rot_deg"] for g in groups])
            rate = 100 * np.array([g["success"] for g in groups])
            se = 100 * np.array([g["se"] for g in groups])
            ax.plot(rot, rate, marker="o", label=method_name(method, d_thresh))
            ax.fill_between(rot, rate - se, rate + se, alpha=0.2)
            ticks.update(
                {g["rot_deg"]: f"{g['rot_deg']:g}°\n{g['trans_mm']:.2g} mm" for g in groups}
            )
        ax.set_xticks(list(ticks), list(ticks.values()), fontsize=8)
        ax.set_xlabel("object pose error (rotation, translation)")
        title = f"pose error ({trials_label(summary)})"
        save_success_figure(fig, ax, path, title)
