"""Both loss criteria side by side for several perturbation-study runs (hands, squeezes).

The paper's criterion says a grasp held while the hull of fingertips and palm still meets the
object's box; the strict one also asks that the object ends within 20 mm and 20 deg of where
the hand held it once the grasp settled (``held_strict`` in every study row). For each run
folder of ``wholehand study perturbation`` (its ``trials.csv``) and each method and pull angle,
this prints both success rates (the mean of grasp-level rates +- 1 standard error across the
grasps, as the study's summary states them) and draws them as bars: the paper's solid, the
strict one hatched.

Run:  python examples/criteria_by_hand.py RUN_DIR[=LABEL] [...] [--png criteria.png]
      python examples/criteria_by_hand.py --quick      (the runs stored in docs/data)

Each run is labelled by its folder's name, or by LABEL given as ``DIR=LABEL``.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path
from typing import Any

from wholehand import success_stats

DOCS_DATA = Path(__file__).resolve().parent.parent / "docs" / "data"
STORED_RUNS = (
    "perturbation-strict=Allegro",
    "perturbation-strict-hx5=HX5-D20",
    "unseen-hands/inspire=Inspire",
    "unseen-hands/svh=Schunk SVH",
    "unseen-hands/shadow=Shadow, 20 N",
    "unseen-hands/ability-squeeze-30=Ability, 30 N",
)
"""The runs behind docs/results.md's figure of both criteria (folders under docs/data)."""


def _typed(row: dict[str, str]) -> dict[str, Any]:
    """A ``trials.csv`` row with the fields :func:`wholehand.success_stats` reads typed."""
    out: dict[str, Any] = dict(row)
    out["held"] = row["held"] == "True"
    if row.get("held_strict") in ("True", "False"):
        out["held_strict"] = row["held_strict"] == "True"
    else:
        out.pop("held_strict", None)
    out["grasp"] = int(row["grasp"])
    return out


def rates(folder: Path, label: str) -> list[dict[str, Any]]:
    """Per (method, pull angle) of the run in ``folder``: both success rates and their SEs,
    the run called ``label``."""
    path = folder / "trials.csv"
    if not path.is_file():
        raise SystemExit(f"{folder}: no trials.csv; give the --out folder of a study run")
    with path.open(newline="") as f:
        rows = [_typed(r) for r in csv.DictReader(f)]
    groups: dict[tuple[str, float], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["method"], float(r["theta_deg"])), []).append(r)
    return [
        {"run": label, "method": method, "theta_deg": theta, **success_stats(group)}
        for (method, theta), group in sorted(groups.items(), key=lambda kv: (kv[0][1], kv[0][0]))
    ]


def plot(table: list[dict[str, Any]], path: Path) -> None:
    """Bars of both criteria per run, method and angle, saved to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    labels = [f"{r['run']}\n{r['method']} {r['theta_deg']:g} deg" for r in table]
    x = np.arange(len(table))
    fig, ax = plt.subplots(figsize=(max(6.0, 0.9 * len(table)), 4.8))
    bars = (
        (-0.2, "success", "se", "", "paper"),
        (0.2, "success_strict", "se_strict", "//", "strict"),
    )
    for offset, key, se, hatch, name in bars:
        values = [100 * r[key] for r in table]
        errors = [100 * r[se] for r in table]
        ax.bar(x + offset, values, 0.4, yerr=errors, hatch=hatch, capsize=3, color="tab:blue",
               alpha=0.45 if hatch else 0.85, label=name)  # fmt: skip
    ax.set_xticks(x, labels, fontsize=7, rotation=30, ha="right")
    ax.set_ylabel("held [%] (mean of grasps +- 1 SE)")
    ax.set_ylim(0, 105)
    ax.legend()
    ax.set_title("paper's criterion and the strict one (20 mm, 20 deg)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="*", help="study --out folders, each as DIR or DIR=LABEL")
    parser.add_argument("--png", type=Path, help="write the bar plot here")
    parser.add_argument(
        "--quick", action="store_true", help="as with no RUN_DIR: the runs stored in docs/data"
    )
    args = parser.parse_args()
    runs = args.runs or [str(DOCS_DATA / name) for name in STORED_RUNS]
    table = []
    for run in runs:
        folder, _, label = run.partition("=")
        table += rates(Path(folder), label or Path(folder).name)
    print(f"{'run':<24} {'method':<16} {'deg':>4} {'paper %':>13} {'strict %':>13} {'grasps':>6}")
    for r in table:
        print(
            f"{r['run']:<24} {r['method']:<16} {r['theta_deg']:>4g} "
            f"{100 * r['success']:>6.1f} +- {100 * r['se']:<4.1f} "
            f"{100 * r['success_strict']:>6.1f} +- {100 * r['se_strict']:<4.1f} {r['n_grasps']:>6}"
        )
    if args.png:
        plot(table, args.png)
        print(f"plot: {args.png}")


if __name__ == "__main__":
    main()
