"""The picture ``wholehand hand check --png`` draws: the hand's surface samples, and the closing
directions and palm normal the controller will use, so that a wrong one shows at a glance."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from wholehand.errors import WholehandError
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics

FloatArray = npt.NDArray[np.float64]

ARROW_LENGTH = 0.04
"""Length of the drawn arrows [m]."""


@dataclass(frozen=True)
class Arrow:
    """A direction to draw, in the hand's base frame (the URDF root)."""

    label: str
    origin: FloatArray
    """(3,) [m]"""
    direction: FloatArray
    """(3,) unit"""
    source: str
    """``"model"`` (derived from the kinematics) or ``"hand.toml"`` (given)."""


def closing_arrows(hand: HandModel) -> list[Arrow]:
    """At the neutral configuration: each fingertip's closing direction (the way its origin
    moves under the power style's closing torques: hand.toml's, else those derived from the
    model), and the palm normal from the middle of the palm link's samples, the model's and
    hand.toml's ``palm_normal`` where given. A direction the model cannot give is left out
    (``hand check`` reports why)."""
    from wholehand.models.grasp_styles import style_arrays, with_close_torque
    from wholehand.models.palm import model_palm_normal, tip_velocities

    q0 = hand.neutral()
    kin = HandKinematics(hand)
    kin.update(q0, np.eye(4))
    cfg = hand.config
    q_pre, tau, _ = style_arrays(hand, with_close_torque(hand, cfg.grasp_styles["power"]))
    source = "hand.toml" if any(cfg.grasp_styles["power"].close_torque.values()) else "model"
    links = np.flatnonzero(hand.link_fingertip)
    tips = np.array([kin.frame_pose(hand.link_names[link])[:3, 3] for link in links])
    velocities = tip_velocities(hand, kin, tips, hand.link_joint[links], tau)
    out: list[Arrow] = []
    for link, tip, velocity in zip(links, tips, velocities, strict=True):
        if np.linalg.norm(velocity) > 1e-9:
            direction = velocity / np.linalg.norm(velocity)
            out.append(Arrow(hand.link_names[link], tip, direction, source))
    rows = hand.samples.link == hand.link_index(hand.palm_link)
    if rows.any():
        palm = kin.transform_points(hand.samples.p_joint[rows], hand.samples.joint[rows])
        centre = 0.5 * (palm.min(axis=0) + palm.max(axis=0))
        try:
            out.append(Arrow("palm normal", centre, model_palm_normal(hand, q_pre, tau), "model"))
        except WholehandError:
            pass
        if cfg.palm_normal is not None:
            given = np.asarray(cfg.palm_normal, dtype=float)
            out.append(Arrow("palm normal", centre, given / np.linalg.norm(given), "hand.toml"))
    return out


def plot_samples(hand: HandModel, path: str | Path) -> Path:
    """PNG of the hand's surface samples at its neutral configuration, coloured by link, seen
    from three sides (base frame axes), with :func:`closing_arrows` drawn on them: fingertips'
    closing directions in black, the palm normal in red (solid: the model's; dashed:
    hand.toml's)."""
    from matplotlib import colormaps
    from matplotlib.figure import Figure

    kin = HandKinematics(hand)
    kin.update(hand.neutral(), np.eye(4))
    p = kin.transform_points(hand.samples.p_joint, hand.samples.joint)
    colours = colormaps["tab20"](hand.samples.link % 20)
    fig = Figure(figsize=(15, 5.5), dpi=100)
    views = (("x", "y", 0, 1), ("x", "z", 0, 2), ("y", "z", 1, 2))
    axes = fig.subplots(1, 3)
    arrows = closing_arrows(hand)
    for ax, (a, b, i, j) in zip(axes, views, strict=True):
        ax.scatter(p[:, i], p[:, j], s=3, c=colours, linewidths=0)
        for arrow in arrows:
            tip = arrow.origin + ARROW_LENGTH * arrow.direction
            palm = arrow.label == "palm normal"
            style = {
                "arrowstyle": "-|>",
                "color": "red" if palm else "black",
                "linestyle": "--" if arrow.source == "hand.toml" and palm else "-",
                "linewidth": 1.5,
            }
            ax.annotate("", (tip[i], tip[j]), (arrow.origin[i], arrow.origin[j]), arrowprops=style)
        ax.set_xlabel(f"{a} [m]")
        ax.set_ylabel(f"{b} [m]")
        ax.set_aspect("equal")
    for k, name in enumerate(hand.link_names):
        axes[2].scatter([], [], s=20, color=colormaps["tab20"](k % 20), label=name)
    axes[2].plot([], [], color="black", label="fingertip closes")
    axes[2].plot([], [], color="red", label="palm normal (model)")
    axes[2].plot([], [], color="red", ls="--", label="palm normal (hand.toml)")
    axes[2].legend(fontsize=6, loc="center left", bbox_to_anchor=(1.02, 0.5), ncols=2)
    fig.suptitle(
        f"{hand.name}: {len(hand.samples)} surface samples on {len(hand.link_names)} links "
        "(neutral configuration, base frame), closing directions and palm normal"
    )
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out)
    return out
