"""Perturbation study (paper Sec. IV-A-1, Fig. 4): success versus rotational-pull angle.

Per grasp and method: at theta = 0 the initial six-direction load test only (one trial); at
theta > 0 the whole protocol (settle, load test, pull by theta about a random axis, load test)
with one random axis per repeat. Methods share the axes (paired seeds). Success is the mean of
grasp-level success rates, +- 1 standard error across them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from wholehand.grasps.store import stored_grasp_indices
from wholehand.models.object_catalogue import PAPER_OBJECTS
from wholehand.studies.base import (
    DEFAULT_HAND,
    METHODS,
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


@dataclass(frozen=True)
class PerturbationConfig:
    """Design of one size of the perturbation study."""

    objects: tuple[str, ...]
    grasps: tuple[int, ...]
    thetas: tuple[float, ...]
    repeats: int
    """Random axes per grasp at each theta > 0 (theta = 0 runs once)."""
    methods: tuple[str, ...] = METHODS


CONFIGS = {
    "full": PerturbationConfig(PAPER_OBJECTS, tuple(range(10)), (0.0, 30.0, 60.0, 90.0), 10),
    "quick": PerturbationConfig(
        ("077_rubiks_cube", "065-f_cups"), (0, 1), (0.0, 30.0, 60.0, 90.0), 1
    ),
    "tiny": PerturbationConfig(("077_rubiks_cube",), (0,), (0.0, 60.0), 1, ("qp", "feedforward")),
}


class PullDesign(Protocol):
    """What :func:`pull_jobs` expands: objects, grasp indices, pull angles, axes per angle."""

    @property
    def objects(self) -> tuple[str, ...]: ...
    @property
    def grasps(self) -> tuple[int, ...]: ...
    @property
    def thetas(self) -> tuple[float, ...]: ...
    @property
    def repeats(self) -> int: ...


Variant = tuple[dict[str, Any], dict[str, Any]]
"""One trial per pull: its labels and its TrialSpec fields, e.g. ``({"method": "qp"},
{"allocator": "qp"})``."""


def pull_jobs(
    cfg: PullDesign,
    seed: int,
    hand: str,
    protocol: dict[str, Any],
    variants: Sequence[Variant],
) -> list[TrialJob]:
    """The jobs of a pull design: per object, stored power grasp, angle and repeat (theta = 0
    once), one trial per variant with its labels (and ``repeat``) and spec fields. Variants
    share the seed of (object, grasp, repeat): the same random pull axis."""
    jobs: list[TrialJob] = []
    for oi, obj in enumerate(cfg.objects):
        for grasp in stored_grasp_indices(hand, obj, "power", cfg.grasps):
            for theta in cfg.thetas:
                for repeat in range(1 if theta == 0.0 else cfg.repeats):
                    trial_seed = derive_seed(seed, oi, grasp, repeat)
                    for labels, fields in variants:
                        spec = TrialSpec(
                            hand=hand,
                            object=obj,
                            grasp=grasp,
                            theta_deg=theta,
                            seed=trial_seed,
                            protocol_params=protocol,
                            **fields,
                        )
                        jobs.append(TrialJob(len(jobs), spec, {**labels, "repeat": repeat}))
    return jobs


class PerturbationStudy(Study):
    name = "perturbation"
    description = "success vs rotational-pull angle per method (paper Fig. 4)"

    def jobs(self, size: str, seed: int, hand: str = DEFAULT_HAND) -> list[TrialJob]:
        cfg = CONFIGS[self.check_size(size)]
        variants = [({"method": m}, {"allocator": m}) for m in cfg.methods]
        return pull_jobs(cfg, seed, hand, protocol_for(size), variants)

    def summarise(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        groups = []
        for (method, theta), group in group_rows(rows, "method", "theta_deg").items():
            groups.append({"method": method, "theta_deg": theta, **success_stats(group)})
        failures: dict[str, dict[str, int]] = {}
        for r in rows:
            if not r["held"]:
                where = failures.setdefault(r["method"], {})
                stage = str(r.get("failure_stage", "")).split(" ")[0]
                where[stage] = where.get(stage, 0) + 1
        return {"groups": groups, "failure_stages": failures}

    def plot(self, rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> None:
        import numpy as np
        from matplotlib.figure import Figure

        fig = Figure(figsize=(5, 3.5))

        ax = fig.subplots()
        by_method = group_rows(summary["groups"], "method")
        for (method,), groups in by_method.items():
            theta = np.array([g["theta_deg"] for g in groups])
            rate = 100 * np.array([g["success"] for g in groups])
            se = 100 * np.array([g["se"] for g in groups])
            (line,) = ax.plot(theta, rate, marker="o", label=method)
            ax.fill_between(theta, rate - se, rate + se, alpha=0.2)
            strict = 100 * np.array([g.get("success_strict", np.nan) for g in groups])
            if np.isfinite(strict).any():  # the strict criterion, dashed in the same colour
                ax.plot(theta, strict, ls="--", marker=".", color=line.get_color(),
                        label=f"{method}, strict")  # fmt: skip
        ax.set_xlabel("rotation of the pull [deg]")
        title = f"{self.name} ({trials_label(summary)})"
        save_success_figure(fig, ax, path, title)
