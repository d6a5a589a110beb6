"""Fast-disturbance study: what real time buys when the disturbance is faster than a period.

The rate study's loads build up over hundreds of milliseconds. Here each trial settles a stored
grasp, then one fast disturbance (:data:`~wholehand.trials.disturbance.DISTURBANCES`: impulses
of 10, 20 and 50 ms on the object, a sudden pull, a knock on one finger) and a recovery. The
controller runs at rates from 30 Hz to 1 kHz, with three tails of its compute time:

- ``none``: computing takes no simulated time (any solver fast enough for its rate);
- ``measured``: each command takes effect after the cycle's compute time measured on this
  computer (the in-process controller as it is, near-loss QP tail included);
- ``measured+deadline``: and the robot controller's 2 ms QP deadline, which keeps the last
  torque when a solve runs past it.

Every variant of a (object, grasp, repeat) faces the same push (paired seeds). Success is the
mean of grasp-level rates +- 1 standard error; each variant is compared with the ideal one
(``none`` at the fastest rate) by the paired difference of grasp-level rates. The ``measured``
tails depend on the computer that ran them (rows keep their cycle times).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from wholehand.grasps.store import stored_grasp_indices
from wholehand.models.object_catalogue import PAPER_OBJECTS
from wholehand.studies.base import (
    DEFAULT_HAND,
    Study,
    TrialJob,
    derive_seed,
    group_rows,
    save_success_figure,
    success_stats,
    trials_label,
)
from wholehand.studies.rate import SHORTFALL_SE, enough_rate, paired_difference
from wholehand.studies.reach import ROBOT_DEADLINE
from wholehand.trials.disturbance import DISTURBANCES
from wholehand.trials.trial import TrialSpec

RATES = (30.0, 100.0, 200.0, 1000.0)
"""Control rates [Hz], the physics step fixed at 1 ms."""

TAILS: dict[str, dict[str, Any]] = {
    "none": {},
    "measured": {"compute_delay": True},
    "measured+deadline": {
        "compute_delay": True,
        "allocator_params": {"options": {"deadline": ROBOT_DEADLINE}},
    },
}
"""Tail label -> TrialSpec fields: how a cycle's compute time acts on the simulation."""
IDEAL = "none"


@dataclass(frozen=True)
class DisturbanceConfig:
    """Design of one size of the fast-disturbance study."""

    objects: tuple[str, ...]
    grasps: tuple[int, ...]
    repeats: int
    """Seeded pushes (direction, or finger) per grasp and disturbance."""
    kinds: tuple[str, ...] = tuple(DISTURBANCES)
    rates: tuple[float, ...] = RATES
    tails: tuple[str, ...] = tuple(TAILS)
    settle_time: float = 0.5
    """[s] before the push."""
    recovery_time: float = 0.5
    """[s] after the push."""


CONFIGS = {
    "full": DisturbanceConfig(PAPER_OBJECTS, (0, 1, 2, 3), 2),
    "quick": DisturbanceConfig(
        ("077_rubiks_cube", "006_mustard_bottle"),
        (0, 1),
        1,
        rates=(30.0, 1000.0),
        tails=("none", "measured+deadline"),
        settle_time=0.3,
        recovery_time=0.3,
    ),
    "tiny": DisturbanceConfig(
        ("077_rubiks_cube",),
        (0,),
        1,
        ("impulse_10ms",),
        (30.0, 1000.0),
        ("none", "measured"),
        0.1,
        0.1,
    ),
}


class DisturbanceStudy(Study):
    name = "disturbance"
    description = (
        "fast disturbances (10-50 ms impulses, a sudden pull, a finger knock) vs control rate "
        "and compute-time tail (what real time buys)"
    )

    def jobs(self, size: str, seed: int, hand: str = DEFAULT_HAND) -> list[TrialJob]:
        cfg = CONFIGS[self.check_size(size)]
        protocol = {"settle_time": cfg.settle_time, "recovery_time": cfg.recovery_time}
        jobs: list[TrialJob] = []
        for oi, obj in enumerate(cfg.objects):
            for grasp in stored_grasp_indices(hand, obj, "power", cfg.grasps):
                for repeat in range(cfg.repeats):
                    trial_seed = derive_seed(seed, oi, grasp, repeat)
                    for kind in cfg.kinds:
                        for tail in cfg.tails:
                            for rate in cfg.rates:
                                spec = TrialSpec(
                                    hand=hand,
                                    object=obj,
                                    grasp=grasp,
                                    seed=trial_seed,
                                    control_rate=rate,
                                    disturbance=kind,
                                    protocol_params=protocol,
                                    **TAILS[tail],
                                )
                                labels = {
                                    "disturbance": kind,
                                    "tail": tail,
                                    "rate_hz": rate,
                                    "repeat": repeat,
                                }
                                jobs.append(TrialJob(len(jobs), spec, labels))
        return jobs

    def summarise(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        groups: list[dict[str, Any]] = []
        enough: list[dict[str, Any]] = []
        for (kind,), block in group_rows(rows, "disturbance").items():
            by_variant = group_rows(block, "tail", "rate_hz")
            ideal_rates = [r for (t, r) in by_variant if t == IDEAL]
            ideal = by_variant.get((IDEAL, max(ideal_rates))) if ideal_rates else None
            for (tail,), tail_block in group_rows(block, "tail").items():
                mine = []
                for (rate,), group in sorted(group_rows(tail_block, "rate_hz").items()):
                    diff, se, n = paired_difference(group, ideal) if ideal else (np.nan, 0.0, 0)
                    cycle = np.array([r.get("cycle_max_us", np.nan) for r in group], dtype=float)
                    mine.append(
                        {
                            "disturbance": kind,
                            "tail": tail,
                            "rate_hz": rate,
                            **success_stats(group),
                            "diff_to_ideal": diff,
                            "diff_se": se,
                            "n_paired": n,
                            "falls_short": bool(n and diff < -SHORTFALL_SE * se),
                            "cycle_max_us": float(np.nanmax(cycle)) if cycle.size else np.nan,
                        }
                    )
                groups += mine
                enough.append({"disturbance": kind, "tail": tail, "enough_hz": _enough(mine)})
        return {"groups": groups, "enough_rate": enough}

    def plot(self, rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> None:
        from matplotlib.figure import Figure

        by_kind = group_rows(summary["groups"], "disturbance")
        fig = Figure(figsize=(2.6 * max(len(by_kind), 1) + 0.6, 3.4))
        axes = np.atleast_1d(fig.subplots(1, max(len(by_kind), 1), sharey=True))
        for ax, ((kind,), groups) in zip(axes, by_kind.items(), strict=False):
            for (tail,), line in group_rows(groups, "tail").items():
                hz = np.array([g["rate_hz"] for g in line])
                rate = 100 * np.array([g["success"] for g in line], dtype=float)
                se = 100 * np.array([g["se"] for g in line], dtype=float)
                ax.plot(hz, rate, marker="o", label=tail)
                ax.fill_between(hz, rate - se, rate + se, alpha=0.15)
            ax.set_xscale("log")
            ax.set_title(kind, fontsize=9)
            ax.set_xlabel("rate [Hz]")
        fig.suptitle(f"{self.name} ({trials_label(summary)})", fontsize=10)
        save_success_figure(fig, axes[0], path)


def _enough(groups: list[dict[str, Any]]) -> float:
    """The lowest rate [Hz] from which on no rate of a tail falls short of the ideal variant
    (:func:`~wholehand.studies.rate.enough_rate`, against the ideal instead of the fastest);
    NaN when even the fastest falls short."""
    shifted = [{**g, "diff_to_fastest": g["diff_to_ideal"]} for g in groups]
    ordered = sorted(shifted, key=lambda g: g["rate_hz"])
    if not ordered or ordered[-1]["falls_short"]:
        return float("nan")
    return enough_rate(shifted)
