"""Contacts-per-link sweep (paper Sec. IV-B-3, Fig. 7): success, QP size and control rate vs K.

The estimator keeps at most K contacts per link (``estimator_params={"k": K}``). Per K: the full
protocol at three pull angles with random axes (repeats per grasp), initial failures included;
success +- 1 standard error across grasp means, the mean QP contact count, and the control rate
1 / (mean cycle time) measured on this machine.
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
    success_stats,
)
from wholehand.studies.perturbation import pull_jobs


@dataclass(frozen=True)
class KSweepConfig:
    objects: tuple[str, ...]
    grasps: tuple[int, ...]
    thetas: tuple[float, ...]
    repeats: int
    ks: tuple[int, ...] = (1, 3, 5, 7)


CONFIGS = {
    "full": KSweepConfig(PAPER_OBJECTS, tuple(range(10)), (30.0, 60.0, 90.0), 5),
    "quick": KSweepConfig(("077_rubiks_cube", "065-f_cups"), (0, 1), (60.0,), 1),
    "tiny": KSweepConfig(("077_rubiks_cube",), (0,), (60.0,), 1, (1, 5)),
}


class KSweepStudy(Study):
    name = "k-sweep"
    description = "success, QP contact count and control rate vs contacts per link K (paper Fig. 7)"

    def jobs(self, size: str, seed: int, hand: str = DEFAULT_HAND) -> list[TrialJob]:
        cfg = CONFIGS[self.check_size(size)]
        variants = [({"k": k}, {"allocator": "qp", "estimator_params": {"k": k}}) for k in cfg.ks]
        return pull_jobs(cfg, seed, hand, protocol_for(size), variants)

    def summarise(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        groups = []
        for (k,), group in group_rows(rows, "k").items():
            contacts = [float(r["contacts_mean"]) for r in group if r.get("cycles")]
            cycle = [float(r["cycle_mean_us"]) for r in group if r.get("cycles")]
            groups.append(
                {
                    "k": k,
                    **success_stats(group),
                    "qp_contacts_mean": float(np.mean(contacts)) if contacts else float("nan"),
                    "control_rate_hz": float(1e6 / np.mean(cycle)) if cycle else float("nan"),
                }
            )
        return {"groups": groups}

    def plot(self, rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> None:
        from matplotlib.figure import Figure

        g = summary["groups"]
        k = np.array([x["k"] for x in g])
        fig = Figure(figsize=(9, 3))
        axes = fig.subplots(1, 3)
        rate, se = 100 * np.array([x["success"] for x in g]), 100 * np.array([x["se"] for x in g])
        axes[0].plot(k, rate, marker="o")
        axes[0].fill_between(k, rate - se, rate + se, alpha=0.2)
        axes[0].set_ylabel("success [%]")
        axes[1].plot(k, [x["qp_contacts_mean"] for x in g], marker="o")
        axes[1].set_ylabel("mean QP contacts")
        axes[2].plot(k, [x["control_rate_hz"] for x in g], marker="o")
        axes[2].set_ylabel("control rate [Hz]")
        for ax in axes:
            ax.set_xlabel("K (contacts per link)")
            ax.set_xticks(k)
        fig.tight_layout()
        fig.savefig(path, dpi=120)
