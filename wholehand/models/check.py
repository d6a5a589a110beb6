"""``wholehand hand check``: what a hand folder gives the controller, and what looks wrong.

The report lists links, joints, actuators, couplings, locked joints, limits and the surface
samples per link, then findings, each with the fix. A URDF is read twice: raw, for what
Pinocchio would silently accept (inverted or missing limits, placeholder efforts), and through
the hand model, for what the controller will see; an MJCF through the hand model. A hand that
does not load at all gets the loader's error as a finding, with every raw finding beside it.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from wholehand.errors import WholehandError
from wholehand.models.hand import HandModel, load_hand
from wholehand.models.hand_config import HandConfig, parse_hand_config, resolve_hand_config

FloatArray = npt.NDArray[np.float64]

PLACEHOLDER_EFFORT = 50.0
"""A URDF effort limit above this [N*m or N] on a hand joint is taken for a placeholder."""
FAR_FROM_LINK = 0.3
"""A link's geometry whose bounding-box centre lies farther than this from the link frame, or
which spans more than this, is reported (wrong origin, or a mesh in millimetres) [m]."""
FEW_SAMPLES = 3
"""Links with fewer surface samples than this are reported."""


@dataclass
class Finding:
    """One problem found, and how to fix it."""

    severity: str
    """``error`` (the hand cannot be used), ``warning`` (it runs, probably not as meant) or
    ``note``."""
    what: str
    fix: str


@dataclass
class HandReport:
    """The result of :func:`check_hand`; :meth:`as_dict` is JSON-serialisable."""

    path: Path
    summary: dict[str, Any] = field(default_factory=dict)
    joints: list[dict[str, Any]] = field(default_factory=list)
    findings: list[Finding] = field(default_factory=list)
    hand: HandModel | None = None

    @property
    def ok(self) -> bool:
        """No error among the findings."""
        return not any(f.severity == "error" for f in self.findings)

    def add(self, severity: str, what: str, fix: str) -> None:
        self.findings.append(Finding(severity, what, fix))

    def as_dict(self) -> dict[str, Any]:
        return {
            "path": str(self.path),
            "ok": self.ok,
            "summary": self.summary,
            "joints": self.joints,
            "findings": [f.__dict__ for f in self.findings],
        }


def _raw_joint_findings(cfg: HandConfig, report: HandReport) -> None:
    """What a URDF's joint tags say that Pinocchio accepts silently."""
    if cfg.model_format != "urdf":
        return
    root = ET.parse(cfg.model_path).getroot()
    placeholders = []
    for joint in root.iter("joint"):
        name, kind = joint.get("name", ""), joint.get("type", "")
        if kind not in ("revolute", "prismatic"):
            continue
        limit = joint.find("limit")
        if limit is None or limit.get("lower") is None or limit.get("upper") is None:
            report.add(
                "error",
                f"joint {name!r} ({kind}) has no lower/upper limit in {cfg.model_path.name}",
                'give it <limit lower="..." upper="..." effort="..." velocity="..."/> from the '
                "hand's data sheet, or lock it in hand.toml ([joints] locked)",
            )
            continue
        lower, upper = float(limit.get("lower", "0")), float(limit.get("upper", "0"))
        if lower > upper:
            report.add(
                "error",
                f"joint {name!r} has inverted limits: lower {lower:g} > upper {upper:g}",
                "swap lower and upper in the URDF",
            )
        effort = float(limit.get("effort", "0"))
        if effort > PLACEHOLDER_EFFORT and name not in cfg.locked_joints:
            placeholders.append(f"{name} ({effort:g})")
    if placeholders and not cfg.torque_limit_set:
        report.add(
            "warning",
            f"{len(placeholders)} joints have URDF effort limits that look like placeholders: "
            f"{', '.join(placeholders[:4])}{' ...' if len(placeholders) > 4 else ''}; wholehand "
            f"ignores them and uses [joints] torque_limit (default {cfg.torque_limit_default:g})",
            "set [joints] torque_limit in hand.toml to the motors' real limits [N*m]",
        )


def _geometry_findings(hand: HandModel, report: HandReport) -> None:
    model = hand.model
    sampled = set(hand.link_names)
    moving_links = [
        f.name
        for f in model.frames
        if f.type.name == "BODY" and f.parentJoint > 0 and f.name not in sampled
    ]
    excluded = set(hand.config.excluded_links)
    bare = [n for n in moving_links if n not in excluded]
    if bare:
        report.add(
            "note",
            f"moving links without {hand.config.sample_surface} geometry (never contacts): {bare}",
            "fine for frames and tip markers; otherwise add geometry to these links",
        )
    counts = np.bincount(hand.samples.link, minlength=len(hand.link_names))
    for i, link in enumerate(hand.link_names):
        mesh = hand.link_mesh(i)
        lo, hi = mesh.bounds
        centre, span = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
        if span > FAR_FROM_LINK or float(np.linalg.norm(centre)) > FAR_FROM_LINK:
            report.add(
                "warning",
                f"link {link!r}: its geometry spans {span:.3g} m, centred "
                f"{float(np.linalg.norm(centre)):.3g} m from its joint frame",
                'a mesh in millimetres needs scale="0.001 0.001 0.001" in the URDF; a mesh far '
                "from its link has a wrong <origin>",
            )
        if counts[i] < FEW_SAMPLES:
            report.add(
                "warning",
                f"link {link!r} has only {counts[i]} surface samples",
                "raise density_per_cm2, or exclude the link if it never touches objects",
            )


def _buried_findings(hand: HandModel, report: HandReport) -> None:
    from wholehand.models.outer_surface import find_buried_samples

    found = find_buried_samples(
        hand.model, hand.collision_model, hand.samples.p_joint, hand.samples.joint
    )
    n, total = int(found.buried.sum()), len(hand.samples)
    report.summary["buried_samples"] = n
    if n and not hand.config.outer_surface_only:
        per_link = np.bincount(hand.samples.link[found.buried], minlength=len(hand.link_names))
        worst = [f"{hand.link_names[i]} ({per_link[i]})" for i in np.argsort(-per_link)[:3]]
        report.add(
            "warning",
            f"{n} of {total} samples ({100.0 * n / total:.1f} %) lie inside other collision "
            f"shapes of the hand and can never touch (most on {', '.join(worst)})",
            "set outer_surface_only = true in hand.toml",
        )
    if found.skipped_shapes:
        report.add(
            "note",
            f"{len(found.skipped_shapes)} collision meshes are not closed surfaces, so samples "
            "inside them cannot be found",
            "close (repair) those meshes if buried samples matter",
        )


def check_hand(name_or_path: str | Path) -> HandReport:
    """Check a hand folder (or shipped hand name); never raises for a broken hand: the loader's
    error becomes a finding."""
    path = resolve_hand_config(name_or_path)
    report = HandReport(path)
    try:
        cfg = parse_hand_config(path)
    except WholehandError as err:
        report.add("error", str(err), "fix hand.toml as the message says")
        return report
    _raw_joint_findings(cfg, report)
    try:
        hand = load_hand(path)
    except WholehandError as err:
        report.add("error", f"the hand does not load: {err}", "fix what the message names")
        return report
    report.hand = hand
    model = hand.model
    for name in hand.joint_names:
        joint = model.joints[model.getJointId(name)]
        i, v = joint.idx_q, joint.idx_v
        mimic = hand.mimics.get(name)
        report.joints.append(
            {
                "name": name,
                "lower": float(hand.q_lower[i]),
                "upper": float(hand.q_upper[i]),
                "actuated": bool(hand.actuated_dofs[v]),
                "arm": bool(hand.arm_dofs[v]),
                "torque_limit": float(hand.tau_max[v]),
                "follows": None if mimic is None else mimic.leader,
            }
        )
    report.summary = hand.summary()
    unlimited = [
        j["name"]
        for j in report.joints
        if not (np.isfinite(j["lower"]) and np.isfinite(j["upper"]))
    ]
    if unlimited and hand.config.model_format == "mjcf":
        report.add(
            "error",
            f"joints without a range in {hand.config.model_path.name}: {unlimited}",
            'give each a range="lower upper" (and limited="true" where the file needs it)',
        )
    if not any(hand.link_fingertip):
        report.add(
            "warning",
            "no fingertip_links: the fingertip-only ablation and the grasp test have nothing",
            "list each finger's distal link in fingertip_links",
        )
    if hand.config.thumb is None:
        report.add(
            "note",
            "no thumb: power grasps (thumb and two fingers) cannot be generated",
            'name the thumb\'s key of [fingers] with thumb = "..."',
        )
    _geometry_findings(hand, report)
    _buried_findings(hand, report)
    return report


def plot_samples(hand: HandModel, path: str | Path) -> Path:
    """PNG of the hand's surface samples at its neutral configuration, coloured by link, seen
    from three sides (base frame axes)."""
    from matplotlib import colormaps
    from matplotlib.figure import Figure

    from wholehand.models.kinematics import HandKinematics

    kin = HandKinematics(hand)
    kin.update(hand.neutral(), np.eye(4))
    p = kin.transform_points(hand.samples.p_joint, hand.samples.joint)
    colours = colormaps["tab20"](hand.samples.link % 20)
    fig = Figure(figsize=(15, 5.5), dpi=100)
    views = (("x", "y", 0, 1), ("x", "z", 0, 2), ("y", "z", 1, 2))
    axes = fig.subplots(1, 3)
    for ax, (a, b, i, j) in zip(axes, views, strict=True):
        ax.scatter(p[:, i], p[:, j], s=3, c=colours, linewidths=0)
        ax.set_xlabel(f"{a} [m]")
        ax.set_ylabel(f"{b} [m]")
        ax.set_aspect("equal")
    for k, name in enumerate(hand.link_names):
        axes[2].scatter([], [], s=20, color=colormaps["tab20"](k % 20), label=name)
    axes[2].legend(fontsize=6, loc="center left", bbox_to_anchor=(1.02, 0.5), ncols=2)
    fig.suptitle(
        f"{hand.name}: {len(hand.samples)} surface samples on {len(hand.link_names)} links "
        "(neutral configuration, base frame)"
    )
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out)
    return out
