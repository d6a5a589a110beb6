"""Every method under DexGraspBench's load test (:mod:`wholehand.trials.dexgraspbench`).

Per stored power grasp of the paper's five objects and method: one test of six directions, the
object at DexGraspBench's 0.1 kg and friction 0.6 (the controllers are told ``mu`` = 0.6 too).
Success is the mean of the grasp-level pass rates, +- 1 standard error, as in the other
studies; the summary also counts where the failures came: while the method closed the grasp
(``settle``, DexGraspBench measures from the pose before closing) or under the push.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from wholehand.grasps.store import stored_grasp_indices
from wholehand.models.object_catalogue import PAPER_OBJECTS
from wholehand.studies.base import (
    DEFAULT_HAND,
    METHODS,
    Study,
    TrialJob,
    group_rows,
    save_success_figure,
    success_stats,
)
from wholehand.studies.models import model
from wholehand.trials.dexgraspbench import FRICTION, run_load_test
from wholehand.trials.outcome import sim_warnings_error
from wholehand.trials.trial import TrialSpec

CONFIGS: dict[str, tuple[tuple[str, ...], tuple[int, ...], tuple[str, ...]]] = {
    "full": (PAPER_OBJECTS, tuple(range(10)), METHODS),
    "quick": (("077_rubiks_cube", "065-f_cups"), (0, 1), METHODS),
    "tiny": (("077_rubiks_cube",), (0,), ("qp", "feedforward")),
}
"""Size -> (objects, grasp indices, methods)."""


def load_test_row(job: TrialJob) -> dict[str, Any]:
    """Run the job's load test; its outcome columns."""
    spec = job.spec
    out = run_load_test(spec, model("hand", spec.hand), model("object", spec.object))
    warnings = out["sim_warnings"]
    return {
        "held": bool(out["held"]),
        "directions_passed": sum(r.passed for r in out["directions"]),
        "failed_direction": out["failed_direction"],
        "failed_in": out["failed_in"],
        "translation_mm": round(1000.0 * out["translation_m"], 3),
        "rotation_deg": round(out["rotation_deg"], 3),
        "step_retries": int(warnings.get("step_retries", 0)),
        "failure_stage": out["failed_in"],
        "error": sim_warnings_error(warnings),
        "wall_time_s": out["wall_time_s"],
    }


class DexGraspBenchStudy(Study):
    name = "dexgraspbench"
    description = (
        "every method under DexGraspBench's load test (gravity off, 0.1 kg, six 1 N pushes of "
        "2 s, fail at 5 cm or 15 deg), so our numbers read next to grasp synthesis's"
    )

    def jobs(self, size: str, seed: int, hand: str = DEFAULT_HAND) -> list[TrialJob]:
        objects, grasps, methods = CONFIGS[self.check_size(size)]
        jobs: list[TrialJob] = []
        for obj in objects:
            for grasp in stored_grasp_indices(hand, obj, "power", grasps):
                for method in methods:
                    spec = TrialSpec(
                        hand=hand,
                        object=obj,
                        grasp=grasp,
                        allocator=method,
                        allocator_params={"mu": FRICTION},
                        seed=seed,
                    )
                    jobs.append(TrialJob(len(jobs), spec, {"method": method}, "load_test"))
        return jobs

    def summarise(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        groups = []
        for (method,), group in group_rows(rows, "method").items():
            valid = [r for r in group if not r.get("error")]
            failed = [r for r in valid if not r["held"]]
            groups.append(
                {
                    "method": method,
                    **success_stats(group),
                    "failed_in_settle": sum(r["failed_in"] == "settle" for r in failed),
                    "failed_in_push": sum(r["failed_in"] == "push" for r in failed),
                    "directions_passed_mean": float(
                        np.mean([int(r["directions_passed"]) for r in valid])
                    )
                    if valid
                    else float("nan"),
                }
            )
        by_object = [
            {"method": method, "object": obj, **success_stats(group)}
            for (method, obj), group in group_rows(rows, "method", "object").items()
        ]
        return {"groups": groups, "by_object": by_object}

    def plot(self, rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> None:
        from matplotlib.figure import Figure

        groups = summary["groups"]
        objects = sorted({c["object"] for c in summary["by_object"]})
        fig = Figure(figsize=(8, 3.4))
        ax = fig.subplots()
        xs = np.arange(len(objects) + 1)  # each object, then all of them
        width = 0.8 / max(len(groups), 1)
        for i, group in enumerate(groups):
            cells = {c["object"]: c for c in summary["by_object"] if c["method"] == group["method"]}
            shown = [cells.get(o, {"success": np.nan, "se": 0.0}) for o in objects] + [group]
            ax.bar(
                xs + (i - 0.5 * (len(groups) - 1)) * width,
                [100.0 * c["success"] for c in shown],
                width,
                yerr=[100.0 * c["se"] for c in shown],
                label=group["method"],
            )
        ax.set_xticks(xs, [*(o.split("_", 1)[-1] for o in objects), "all"], fontsize=8)
        save_success_figure(fig, ax, path, "DexGraspBench load test (0.1 kg, 1 N, 5 cm / 15 deg)")
