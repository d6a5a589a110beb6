"""Contact-count study (paper Sec. IV-A-2, Fig. 3): success versus ground-truth contacts.

Every grasp runs the initial six-direction load test (theta = 0) with each method; trials are
binned by the number of MuJoCo contacts at initialisation, N_c^gt (the contacts the baselines
allocate over; ours uses only its own estimate), with the last bin open (>= ``OPEN_BIN``).
The full design runs every stored grasp of every object with shipped power grasps of the hand:
``wholehand grasps generate --object all`` makes them for each YCB mesh that yields one.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wholehand.grasps.store import objects_with_grasps, stored_grasp_indices
from wholehand.models.object_catalogue import PAPER_OBJECTS
from wholehand.studies.base import (
    DEFAULT_HAND,
    METHODS,
    Study,
    TrialJob,
    group_rows,
    protocol_for,
    save_success_figure,
)
from wholehand.trials.trial import TrialSpec

OPEN_BIN = 10
"""Contact counts at or above this share one bin (the paper's ">= 10")."""


"""The hand whose shipped grasps the study runs."""


@dataclass(frozen=True)
class ContactsConfig:
    objects: tuple[str, ...] | None
    """Objects; None: every object with stored power grasps of the hand."""
    grasps: tuple[int, ...] | None
    """Grasp indices per object (those stored); None: every stored grasp."""
    methods: tuple[str, ...] = METHODS


CONFIGS = {
    "full": ContactsConfig(None, None),
    "quick": ContactsConfig(PAPER_OBJECTS, (0, 1, 2)),
    "tiny": ContactsConfig(("077_rubiks_cube",), (0, 4), ("qp", "feedforward")),
}


def contact_bin(n: int | None) -> str:
    """Bin label of a ground-truth contact count."""
    if n is None or n == "":
        return "?"
    n = int(n)
    return f">={OPEN_BIN}" if n >= OPEN_BIN else str(n)


class ContactsStudy(Study):
    name = "contacts"
    description = "success vs ground-truth contact count at initialisation (paper Fig. 3)"

    def jobs(self, size: str, seed: int, hand: str = DEFAULT_HAND) -> list[TrialJob]:
        cfg = CONFIGS[self.check_size(size)]
        objects = objects_with_grasps(hand) if cfg.objects is None else cfg.objects
        jobs: list[TrialJob] = []
        for obj in objects:
            for grasp in stored_grasp_indices(hand, obj, "power", cfg.grasps):
                for method in cfg.methods:
                    spec = TrialSpec(
                        hand=hand,
                        object=obj,
                        grasp=grasp,
                        allocator=method,
                        theta_deg=0.0,
                        seed=seed,
                        protocol_params=protocol_for(size),
                    )
                    jobs.append(TrialJob(len(jobs), spec, {"method": method}))
        return jobs

    def summarise(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        bins = []
        # Errored or diverged trials say nothing about the controller (as in success_stats).
        valid = [r for r in rows if not r.get("error")]
        keyed = [{**r, "bin": contact_bin(r.get("n_contacts_gt_init"))} for r in valid]
        order = sorted(
            {r["bin"] for r in keyed},
            key=lambda b: (
                b.startswith(">"),
                b == "?",
                int(b.strip(">=")) if b[-1].isdigit() else 0,
            ),
        )
        for (method,), group in group_rows(keyed, "method").items():
            per_bin = group_rows(group, "bin")
            for b in order:
                members = per_bin.get((b,), [])
                if members:
                    held = sum(bool(r["held"]) for r in members)
                    bins.append(
                        {
                            "method": method,
                            "bin": b,
                            "n": len(members),
                            "success": held / len(members),
                        }
                    )
        settle_failures = {
            method: sum(1 for r in group if str(r.get("failure_stage", "")) == "settle")
            for (method,), group in group_rows(rows, "method").items()
        }
        return {
            "bins": bins,
            "bin_order": order,
            "settle_failures": settle_failures,
            "n_excluded": len(rows) - len(valid),
        }

    def plot(self, rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> None:
        import numpy as np
        from matplotlib.figure import Figure

        order = summary["bin_order"]
        methods = list(dict.fromkeys(b["method"] for b in summary["bins"]))
        width = 0.8 / max(len(methods), 1)
        fig = Figure(figsize=(6, 3.5))
        ax = fig.subplots()
        for i, method in enumerate(methods):
            rate = {b["bin"]: b["success"] for b in summary["bins"] if b["method"] == method}
            x = np.arange(len(order)) + (i - (len(methods) - 1) / 2) * width
            ax.bar(x, [100 * rate.get(b, np.nan) for b in order], width, label=method)
        counts = (
            {b["bin"]: b["n"] for b in summary["bins"] if b["method"] == methods[0]}
            if methods
            else {}
        )
        ax.set_xticks(
            np.arange(len(order)), [f"{b}\nn={counts.get(b, 0)}" for b in order], fontsize=8
        )
        ax.set_xlabel("ground-truth contacts at initialisation")
        save_success_figure(fig, ax, path)
