"""Grasps found per object and the time per grasp: the optimiser against the pre-shape generator.

Per object, setting (``air``: the object held in front of the palm; ``table``: resting on one of
its stable faces, the hand from above) and generator (``preshape``:
:func:`~wholehand.grasps.generate.generate_grasps`; ``optimize``:
:func:`~wholehand.grasps.optimized.synthesize_grasps`), one job runs the generator as
``wholehand grasps generate`` does, up to ``COUNT`` grasps within the generator's candidate
budget, and records the grasps it found, the candidates it tried, why it rejected the others
and its wall time. The budgets differ because the candidates' costs do: a pre-shape candidate
is one closing in MuJoCo or less (rejected before it: tens of ms), an optimised one a share of a
batch optimisation as well (0.05-0.1 s). The time per grasp is the measure of cost.

On a table the optimiser tries the hand's styles of :data:`STYLES` in turn, as ``wholehand
grasps generate --type power,pinch`` does: pinch for what power left of ``COUNT``, each with the
whole budget. A row keeps each style's grasps, candidates and seconds (``by_style``), so that the
power grasps alone read as before.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from wholehand.models.object_catalogue import PAPER_OBJECTS, available_objects
from wholehand.studies.base import DEFAULT_HAND, Study, TrialJob, derive_seed, group_rows
from wholehand.studies.models import model
from wholehand.trials.trial import TrialSpec

GENERATORS = ("preshape", "optimize")
"""The grasp generators compared: ``wholehand grasps generate --method ...``."""
SETTINGS = ("air", "table")
"""Where the object is: held in the air in front of the palm, or resting on a table."""
COUNT = 10
"""Grasps asked for per object (the generators stop there)."""
STYLES = {"air": ("power",), "table": ("power", "pinch")}
"""The grasp styles the optimiser tries in turn per setting, those of them the hand defines
(the pre-shape generator makes power grasps alone: its other styles would need closing
torques): on a table, a pinch for the small and low objects a power grasp cannot reach from
above."""


@dataclass(frozen=True)
class GraspSynthesisConfig:
    """One study size: objects (None: every YCB mesh) and candidate budget per generator."""

    objects: tuple[str, ...] | None
    budgets: dict[str, int]
    """Generator -> most candidates tried per object."""


CONFIGS: dict[str, GraspSynthesisConfig] = {
    "full": GraspSynthesisConfig(None, {"preshape": 400, "optimize": 128}),
    "quick": GraspSynthesisConfig(PAPER_OBJECTS, {"preshape": 100, "optimize": 32}),
    "tiny": GraspSynthesisConfig(("077_rubiks_cube",), {"preshape": 4, "optimize": 2}),
}


def generation_row(job: TrialJob) -> dict[str, Any]:
    """Run the job's grasp generator in each of its styles in turn; its outcome columns
    (``error`` empty: generation never fails a row by finding nothing)."""
    from wholehand.grasps.generate import generate_grasps
    from wholehand.grasps.optimized import synthesize_grasps

    spec, labels = job.spec, job.labels
    hand = model("hand", spec.hand)
    defined = hand.config.grasp_styles
    styles = [style for style in str(labels["styles"]).split(",") if style in defined]
    make = synthesize_grasps if labels["generator"] == "optimize" else generate_grasps
    found: list[Any] = []
    rejected: Counter[str] = Counter()
    by_style: dict[str, dict[str, float]] = {}
    started = time.perf_counter()
    for style in styles:
        if len(found) >= COUNT:
            break
        begun = time.perf_counter()
        grasps, info = make(
            hand,
            model("object", spec.object),
            count=COUNT - len(found),
            seed=spec.seed,
            max_candidates=int(labels["budget"]),
            style=style,
            on_table=labels["setting"] == "table",
        )
        found += grasps
        rejected.update(cast(dict[str, int], info["rejected"]))
        by_style[style] = {
            "grasps": len(grasps),
            "candidates": cast(int, info["candidates_tried"]),
            "seconds": round(time.perf_counter() - begun, 3),
        }
    wall = time.perf_counter() - started
    return {
        "grasps": len(found),
        "candidates": int(sum(v["candidates"] for v in by_style.values())),
        "contacts_mean": float(np.mean([g.contacts for g in found])) if found else None,
        "top_rejection": max(rejected, key=lambda k: rejected[k]) if rejected else "",
        "rejections": json.dumps(dict(rejected), sort_keys=True),
        "by_style": json.dumps(by_style),
        "error": "",
        "wall_time_s": round(wall, 3),
    }


def _group_summary(group: list[dict[str, Any]]) -> dict[str, Any]:
    valid = [r for r in group if not r.get("error")]
    found = np.array([int(r["grasps"]) for r in valid], dtype=float)
    seconds = float(sum(float(r["wall_time_s"]) for r in valid))
    total = int(found.sum())
    reasons: Counter[str] = Counter()
    for r in valid:
        reasons.update(json.loads(r["rejections"]))
    styles: dict[str, dict[str, Any]] = {}
    for r in valid:
        for style, got in json.loads(r.get("by_style") or "{}").items():
            cell = styles.setdefault(style, {"objects_with_grasp": 0, "grasps": 0, "seconds": 0.0})
            cell["objects_with_grasp"] += int(got["grasps"] > 0)
            cell["grasps"] += int(got["grasps"])
            cell["seconds"] += float(got["seconds"])
    for cell in styles.values():
        cell["seconds"] = round(cell["seconds"], 1)
    return {
        "n_objects": len(valid),
        "n_errors": len(group) - len(valid),
        "objects_with_grasp": int((found > 0).sum()),
        "share_with_grasp": float((found > 0).mean()) if valid else float("nan"),
        "grasps": total,
        "grasps_per_object": float(found.mean()) if valid else float("nan"),
        "grasps_per_object_se": float(found.std(ddof=1) / np.sqrt(found.size))
        if found.size > 1
        else 0.0,
        "candidates": int(sum(int(r["candidates"]) for r in valid)),
        "seconds": round(seconds, 1),
        "seconds_per_grasp": seconds / total if total else float("nan"),
        "rejections": dict(reasons.most_common()),
        "objects_without_grasp": sorted(r["object"] for r in valid if int(r["grasps"]) == 0),
        "by_style": styles,
    }


class GraspSynthesisStudy(Study):
    name = "grasp-synthesis"
    description = (
        "grasps found per object and seconds per grasp: the optimiser (--method optimize) "
        "against the pre-shape generator, in the air and on a table, on every YCB object"
    )

    def jobs(self, size: str, seed: int, hand: str = DEFAULT_HAND) -> list[TrialJob]:
        config = CONFIGS[self.check_size(size)]
        objects = config.objects if config.objects is not None else tuple(available_objects())
        jobs: list[TrialJob] = []
        for i, obj in enumerate(objects):
            for s, setting in enumerate(SETTINGS):
                spec = TrialSpec(hand=hand, object=obj, seed=derive_seed(seed, i, s))
                for generator in GENERATORS:
                    styles = STYLES[setting] if generator == "optimize" else ("power",)
                    labels = {
                        "setting": setting,
                        "generator": generator,
                        "budget": config.budgets[generator],
                        "styles": ",".join(styles),
                    }
                    jobs.append(TrialJob(len(jobs), spec, labels, "grasp_generation"))
        return jobs

    def summarise(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        groups = [
            {"setting": setting, "generator": generator, **_group_summary(group)}
            for (setting, generator), group in group_rows(rows, "setting", "generator").items()
        ]
        return {"groups": groups, "count": COUNT}

    def plot(self, rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> None:
        from matplotlib.figure import Figure

        groups = summary["groups"]
        fig = Figure(figsize=(8, 3.4))
        share, cost = fig.subplots(1, 2)
        xs = np.arange(len(SETTINGS))
        width = 0.8 / len(GENERATORS)
        for i, generator in enumerate(GENERATORS):
            cells = {g["setting"]: g for g in groups if g["generator"] == generator}
            shown = [cells.get(s) for s in SETTINGS]
            offset = xs + (i - 0.5 * (len(GENERATORS) - 1)) * width
            share.bar(
                offset,
                [100.0 * c["share_with_grasp"] if c else np.nan for c in shown],
                width,
                label=generator,
            )
            cost.bar(
                offset,
                [c["seconds_per_grasp"] if c else np.nan for c in shown],
                width,
                label=generator,
            )
        share.set_ylabel("objects with a grasp [%]")
        share.set_ylim(0, 105)
        cost.set_ylabel("seconds per grasp")
        cost.set_yscale("log")
        for ax in (share, cost):
            ax.set_xticks(xs, list(SETTINGS))
            ax.legend(fontsize=8)
        n = max((g["n_objects"] for g in groups), default=0)
        fig.suptitle(f"{Path(summary.get('hand', DEFAULT_HAND)).name}: {n} objects", fontsize=10)
        fig.tight_layout()
        fig.savefig(path, dpi=120)
