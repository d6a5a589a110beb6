"""Per-run PNG: contact count, residual wrench norms, joint torques and QP time over time.

Protocol phase boundaries are drawn as vertical lines labelled with the phase name on the top
panel.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wholehand.loop.record import RunRecord

PANELS = ("contacts", "residual wrench", "joint torques", "QP time")
"""Panels of :func:`plot_run`, top to bottom."""


def phase_boundaries(record: RunRecord) -> list[tuple[float, str]]:
    """(start time [s], phase name) of every protocol phase the record reached, in order."""
    a = record.arrays()
    if a["t"].size == 0:
        return []
    starts = np.r_[0, np.flatnonzero(np.diff(a["phase"])) + 1]
    return [(float(a["t"][i]), record.phases[int(a["phase"][i])]) for i in starts]


def plot_run(record: RunRecord, path: str | Path, title: str | None = None) -> Path:
    """Write the four-panel summary of a run as a PNG (matplotlib Agg; no display needed)."""
    from matplotlib.figure import Figure

    a = record.arrays()
    t = a["t"]
    fig = Figure(figsize=(10, 9), dpi=100)
    axes = fig.subplots(len(PANELS), 1, sharex=True)
    ax_n, ax_w, ax_tau, ax_qp = axes
    if t.size:
        ax_n.step(t, a["n_contacts"], where="post", color="k", lw=1)
        w = a["residual_wrench"].reshape(-1, 6)
        ax_w.plot(t, np.linalg.norm(w[:, :3], axis=1), label="|f_res| [N]", lw=1)
        ax_w.plot(t, np.linalg.norm(w[:, 3:], axis=1), label="|tau_res| [N*m]", lw=1)
        ax_w.legend(loc="upper right", fontsize=8)
        tau = a["tau"].reshape(t.size, -1)
        ax_tau.plot(t, tau, lw=0.6)
        ax_qp.plot(t, 1e6 * a["qp_time"], color="tab:red", lw=0.6)
        for start, name in phase_boundaries(record):
            for ax in axes:
                ax.axvline(start, color="0.6", lw=0.6, ls="--")
            ax_n.annotate(
                name,
                (start, 1.0),
                xycoords=("data", "axes fraction"),
                rotation=90,
                fontsize=7,
                va="top",
                ha="right",
                color="0.3",
            )
    ax_n.set_ylabel("contacts")
    ax_w.set_ylabel("residual wrench")
    ax_tau.set_ylabel("tau [N*m]")
    ax_qp.set_ylabel("QP time [us]")
    ax_qp.set_xlabel("t [s]")
    spec = record.meta.get("spec") or {}
    fig.suptitle(
        title
        or f"{spec.get('hand', '?')} / {spec.get('object', '?')} grasp {spec.get('grasp', '?')}"
    )
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    return path
