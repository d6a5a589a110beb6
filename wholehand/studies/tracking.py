"""Tracking study: success when the object pose comes from a tracker (paper Sec. V-D, open).

The paper's simulations give the controller the exact pose every cycle; its robot gets it from a
tracker at 30 Hz with about 33 ms latency, and the paper leaves rate, latency, noise and tracking
loss unevaluated. Here the 50 paper grasps go through the perturbation protocol (one pull of
``theta`` about a seeded axis per grasp) with the pose delivered through the observation filters
of :attr:`~wholehand.trials.trial.TrialSpec.tracking`, one factor at a time around the paper's
point (30 Hz, 33 ms), plus the exact pose and the worst corner:

- rate 15 / 30 / 60 / 200 Hz at 33 ms;
- latency 0 / 33 / 66 / 100 ms at 30 Hz;
- white noise on each frame, 0 / 1 / 3 mm per axis and 0 / 1 / 3 deg (paired levels);
- a dropout of 0 / 0.2 / 1 s (no new pose) from the start of the pull, where the object moves;
- the corner: 15 Hz, 100 ms, 3 mm and 3 deg, 1 s dropout.

Methods: ``qp`` with contacts estimated at ``q(stamp_object)`` (the paper's loop), ``qp@current``
(contacts at the current q with the stale pose), ``feedforward`` and ``fingertip_only``. All
methods and conditions of a grasp share its pull axis and its noise draws. Success is the mean of
grasp-level rates, +- 1 standard error across grasps.
"""

from __future__ import annotations

import dataclasses
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
from wholehand.trials.protocol import PerturbationProtocol
from wholehand.trials.trial import TrialSpec


@dataclass(frozen=True)
class TrackingCondition:
    """How the pose reaches the controller in one condition; ``rate_hz`` None is the exact
    pose every cycle."""

    name: str
    factor: str
    """The factor varied from the paper's point: ``rate``, ``latency``, ``noise``, ``dropout``,
    or ``reference`` (the exact pose, the paper's point) and ``corner``."""
    rate_hz: float | None = 30.0
    latency_s: float = 0.033
    noise_mm: float = 0.0
    noise_deg: float = 0.0
    dropout_s: float = 0.0

    def tracking(self, pull_start: float, noise_seed: int) -> dict[str, Any]:
        """The :attr:`TrialSpec.tracking` of this condition; a dropout starts at ``pull_start``
        [s of backend time]."""
        if self.rate_hz is None:
            return {}
        out: dict[str, Any] = {"rate_hz": self.rate_hz, "latency_s": self.latency_s}
        if self.noise_mm or self.noise_deg:
            out.update(noise_mm=self.noise_mm, noise_deg=self.noise_deg, noise_seed=noise_seed)
        if self.dropout_s:
            out["dropouts"] = [[pull_start, self.dropout_s]]
        return out

    def level(self) -> float:
        """The value of the varied factor (rate [Hz], latency [ms], noise [mm], dropout [s])."""
        values = {
            "rate": self.rate_hz or 0.0,
            "latency": 1e3 * self.latency_s,
            "noise": self.noise_mm,
            "dropout": self.dropout_s,
        }
        return float(values.get(self.factor, 0.0))


PAPER_POINT = TrackingCondition("30 Hz, 33 ms", "reference")
CONDITIONS: tuple[TrackingCondition, ...] = (
    TrackingCondition("exact", "reference", rate_hz=None, latency_s=0.0),
    PAPER_POINT,
    TrackingCondition("15 Hz", "rate", rate_hz=15.0),
    TrackingCondition("60 Hz", "rate", rate_hz=60.0),
    TrackingCondition("200 Hz", "rate", rate_hz=200.0),
    TrackingCondition("0 ms", "latency", latency_s=0.0),
    TrackingCondition("66 ms", "latency", latency_s=0.066),
    TrackingCondition("100 ms", "latency", latency_s=0.1),
    TrackingCondition("noise 1 mm, 1 deg", "noise", noise_mm=1.0, noise_deg=1.0),
    TrackingCondition("noise 3 mm, 3 deg", "noise", noise_mm=3.0, noise_deg=3.0),
    TrackingCondition("dropout 0.2 s", "dropout", dropout_s=0.2),
    TrackingCondition("dropout 1 s", "dropout", dropout_s=1.0),
    TrackingCondition("corner", "corner", 15.0, 0.1, 3.0, 3.0, 1.0),
)
"""The conditions: the exact pose, the paper's point, one factor at a time, the worst corner."""
FACTORS = ("rate", "latency", "noise", "dropout")

METHODS: dict[str, tuple[str, str]] = {
    "qp": ("qp", "object_stamp"),
    "qp@current": ("qp", "current"),
    "feedforward": ("feedforward", "object_stamp"),
    "fingertip_only": ("fingertip_only", "object_stamp"),
}
"""Method label -> (allocator, where contacts are estimated: ``TrialSpec.estimate_at``)."""


@dataclass(frozen=True)
class TrackingConfig:
    objects: tuple[str, ...]
    grasps: tuple[int, ...]
    conditions: tuple[str, ...]
    methods: tuple[str, ...] = tuple(METHODS)
    theta_deg: float = 60.0


CONFIGS = {
    "full": TrackingConfig(PAPER_OBJECTS, tuple(range(10)), tuple(c.name for c in CONDITIONS)),
    "quick": TrackingConfig(
        ("077_rubiks_cube", "065-f_cups"),
        (0, 1),
        ("exact", "30 Hz, 33 ms", "15 Hz", "100 ms", "noise 3 mm, 3 deg", "dropout 1 s", "corner"),
    ),
    "tiny": TrackingConfig(("077_rubiks_cube",), (0,), ("exact", "corner"), ("qp", "qp@current")),
}


def condition(name: str) -> TrackingCondition:
    """The condition called ``name``."""
    return next(c for c in CONDITIONS if c.name == name)


def pull_start(protocol: dict[str, Any], theta_deg: float) -> float:
    """Backend time [s] at which the protocol's pull starts (the loop starts at 0)."""
    t = 0.0
    for phase in PerturbationProtocol(theta_deg=theta_deg, **protocol).phases():
        if phase.kind == "rotate":
            return round(t, 9)  # 0.4, not 0.39999999999999997, in the rows
        t += phase.duration
    raise ValueError("the protocol has no pull (theta_deg must be > 0)")


class TrackingStudy(Study):
    name = "tracking"
    description = "success vs tracker rate, latency, noise and dropouts (paper Sec. V-D, open)"

    def jobs(self, size: str, seed: int, hand: str = DEFAULT_HAND) -> list[TrialJob]:
        cfg = CONFIGS[self.check_size(size)]
        protocol = protocol_for(size)
        start = pull_start(protocol, cfg.theta_deg)
        grasps = {obj: stored_grasp_indices(hand, obj, "power", cfg.grasps) for obj in cfg.objects}
        # Grasp rank outermost: a run cut short (the runner goes in index order) has the same
        # grasps of every object under every condition and method.
        order = [
            (oi, obj, grasps[obj][rank])
            for rank in range(max(map(len, grasps.values()), default=0))
            for oi, obj in enumerate(cfg.objects)
            if rank < len(grasps[obj])
        ]
        jobs: list[TrialJob] = []
        for oi, obj, grasp in order:
            trial_seed = derive_seed(seed, oi, grasp, 0)
            for name in cfg.conditions:
                cond = condition(name)
                for method in cfg.methods:
                    allocator, estimate_at = METHODS[method]
                    spec = TrialSpec(
                        hand=hand,
                        object=obj,
                        grasp=grasp,
                        allocator=allocator,
                        estimate_at=estimate_at,
                        theta_deg=cfg.theta_deg,
                        seed=trial_seed,
                        protocol_params=protocol,
                        tracking=cond.tracking(start, trial_seed),
                    )
                    labels = {
                        "method": method,
                        "condition": cond.name,
                        "factor": cond.factor,
                        "level": cond.level(),
                    }
                    jobs.append(TrialJob(len(jobs), spec, labels))
        return jobs

    def summarise(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        groups = []
        for (method, name), group in group_rows(rows, "method", "condition").items():
            cond = condition(name)
            groups.append(
                {
                    "method": method,
                    "condition": name,
                    "factor": cond.factor,
                    "level": cond.level(),
                    **success_stats(group),
                }
            )
        return {"groups": groups}

    def plot(self, rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> None:
        import numpy as np
        from matplotlib.figure import Figure

        units = {"rate": "rate [Hz]", "latency": "latency [ms]", "noise": "noise [mm, deg]"}
        units["dropout"] = "dropout at the pull [s]"
        fig = Figure(figsize=(10, 3.2))
        axes = fig.subplots(1, len(FACTORS), sharey=True)
        by_method = group_rows(summary["groups"], "method")
        for ax, factor in zip(axes, FACTORS, strict=True):
            paper_level = dataclasses.replace(PAPER_POINT, factor=factor).level()
            for k, (method, groups) in enumerate(by_method.items()):
                # The paper's point belongs to every factor, at that factor's paper value; the
                # exact pose (dashed) and the corner (dotted) are levels of none.
                points = [(g["level"], g) for g in groups if g["factor"] == factor]
                points += [(paper_level, g) for g in groups if g["condition"] == PAPER_POINT.name]
                points.sort(key=lambda p: p[0])
                x = np.array([p[0] for p in points])
                rate = 100 * np.array([p[1]["success"] for p in points])
                se = 100 * np.array([p[1]["se"] for p in points])
                ax.plot(x, rate, marker="o", color=f"C{k}", label=method)
                ax.fill_between(x, rate - se, rate + se, color=f"C{k}", alpha=0.15)
                for g in groups:
                    style = {"exact": "--", "corner": ":"}.get(g["condition"])
                    if style:
                        ax.axhline(100 * g["success"], ls=style, lw=0.8, color=f"C{k}")
            ax.set_xlabel(units[factor])
        axes[0].set_ylabel("success [%]")
        title = f"tracking ({trials_label(summary)})"
        save_success_figure(fig, axes[0], path, title)
