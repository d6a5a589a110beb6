"""Control-rate study: does a faster loop hold more grasps, and from which rate on does it stop
mattering?

The paper's K sweep (Fig. 7) changes two things at once: more contact points per link and a
slower loop. Here K stays at the default and the physics step at 1 ms; only the controller's
rate changes (the command is held between its cycles). Per grasp, pull angle and repeat: the
whole perturbation protocol at each rate, with the same random pull axis for every rate and
method (paired seeds, those of the perturbation study). Success is the mean of grasp-level
rates +- 1 standard error; each rate is also compared with the fastest one by the paired
difference of grasp-level rates.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from wholehand.models.object_catalogue import PAPER_OBJECTS
from wholehand.studies.base import (
    DEFAULT_HAND,
    Study,
    TrialJob,
    group_rows,
    protocol_for,
    save_success_figure,
    success_stats,
    trials_label,
)
from wholehand.studies.perturbation import pull_jobs

RATES = (30.0, 66.0, 100.0, 200.0, 227.0, 500.0, 1000.0)
"""Control rates [Hz]: the paper's 227 Hz (K = 1) and 66 Hz (K = 7), this project's default
200 Hz, and a sweep from 30 Hz to the 1 kHz of the physics step."""


@dataclass(frozen=True)
class RateConfig:
    """Design of one size of the rate study."""

    objects: tuple[str, ...]
    grasps: tuple[int, ...]
    thetas: tuple[float, ...]
    repeats: int
    """Random pull axes per grasp and angle."""
    rates: tuple[float, ...] = RATES
    methods: tuple[str, ...] = ("qp", "fingertip_only")


CONFIGS = {
    "full": RateConfig(PAPER_OBJECTS, tuple(range(10)), (60.0, 90.0), 3),
    "quick": RateConfig(("077_rubiks_cube", "065-f_cups"), (0, 1), (60.0, 90.0), 1),
    "tiny": RateConfig(("077_rubiks_cube",), (0,), (60.0,), 1, (30.0, 1000.0), ("qp",)),
}


def _grasp_rates(rows: list[dict[str, Any]]) -> dict[tuple[Any, ...], float]:
    """Grasp-level success rates of valid rows, by (object, grasp)."""
    out: dict[tuple[Any, ...], list[bool]] = {}
    for r in rows:
        if not r.get("error"):
            out.setdefault((r["object"], int(r["grasp"])), []).append(bool(r["held"]))
    return {k: float(np.mean(v)) for k, v in out.items()}


def paired_difference(
    rows: list[dict[str, Any]], reference: list[dict[str, Any]]
) -> tuple[float, float, int]:
    """Mean difference of grasp-level success rates, ``rows`` minus ``reference``, over the
    grasps both hold valid trials of, its standard error and the number of grasps."""
    mine, ref = _grasp_rates(rows), _grasp_rates(reference)
    common = sorted(set(mine) & set(ref))
    d = np.array([mine[k] - ref[k] for k in common], dtype=float)
    if d.size == 0:
        return float("nan"), float("nan"), 0
    se = float(d.std(ddof=1) / np.sqrt(d.size)) if d.size > 1 else 0.0
    return float(d.mean()), se, int(d.size)


SHORTFALL_SE = 2.0
"""A rate falls short of the fastest when its paired difference is below minus this many
standard errors (one-sided, about 2 % by chance per rate)."""


def enough_rate(groups: list[dict[str, Any]]) -> float:
    """The lowest rate [Hz] from which on no rate holds fewer grasps than the fastest by more
    than :data:`SHORTFALL_SE` standard errors of the paired difference: above it, speed stops
    mattering. A slower rate that holds more is no shortfall. The fastest rate itself when the
    next slower one already falls short."""
    ordered = sorted(groups, key=lambda g: g["rate_hz"])
    found = float(ordered[-1]["rate_hz"])
    for g in reversed(ordered[:-1]):
        if g["n_paired"] == 0 or g["diff_to_fastest"] < -SHORTFALL_SE * g["diff_se"]:
            break
        found = float(g["rate_hz"])
    return found


class RateStudy(Study):
    name = "rate"
    description = (
        "success vs control rate at a fixed physics step, 60 and 90 deg pulls (what the speed buys)"
    )

    def jobs(self, size: str, seed: int, hand: str = DEFAULT_HAND) -> list[TrialJob]:
        cfg = CONFIGS[self.check_size(size)]
        variants = [
            ({"method": m, "rate_hz": r}, {"allocator": m, "control_rate": r})
            for r in cfg.rates
            for m in cfg.methods
        ]
        # The perturbation study's design and seeds: the same pull axes.
        return pull_jobs(cfg, seed, hand, protocol_for(size), variants)

    def summarise(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        groups: list[dict[str, Any]] = []
        enough: list[dict[str, Any]] = []
        for (method, theta), block in group_rows(rows, "method", "theta_deg").items():
            by_rate = group_rows(block, "rate_hz")
            fastest = by_rate[(max(r for (r,) in by_rate),)]
            mine = []
            for (rate,), group in sorted(by_rate.items()):
                diff, se, n = paired_difference(group, fastest)
                mine.append(
                    {
                        "method": method,
                        "theta_deg": theta,
                        "rate_hz": rate,
                        **success_stats(group),
                        "diff_to_fastest": diff,
                        "diff_se": se,
                        "n_paired": n,
                    }
                )
            groups += mine
            enough.append({"method": method, "theta_deg": theta, "enough_hz": enough_rate(mine)})
        return {"groups": groups, "enough_rate": enough}

    def plot(self, rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> None:
        from matplotlib.figure import Figure

        fig = Figure(figsize=(5.5, 3.5))
        ax = fig.subplots()
        for (method, theta), groups in group_rows(summary["groups"], "method", "theta_deg").items():
            hz = np.array([g["rate_hz"] for g in groups])
            rate = 100 * np.array([g["success"] for g in groups], dtype=float)
            se = 100 * np.array([g["se"] for g in groups], dtype=float)
            ax.plot(hz, rate, marker="o", label=f"{method}, {theta:g} deg")
            ax.fill_between(hz, rate - se, rate + se, alpha=0.15)
        ax.set_xscale("log")
        ax.set_xlabel("control rate [Hz] (physics step 1 ms)")
        save_success_figure(fig, ax, path, f"{self.name} ({trials_label(summary)})")
