"""``wholehand hand check``: what a hand folder gives the controller, and what looks wrong.

The report lists links, joints, actuators, couplings, locked joints, limits and the surface
samples per link, then findings, each with the fix. A URDF is read twice: raw, for what
Pinocchio would silently accept (inverted or missing limits, placeholder efforts), and through
the hand model, for what the controller will see; an MJCF through the hand model. A hand that
does not load at all gets the loader's error as a finding, with every raw finding beside it.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from wholehand.errors import WholehandError
from wholehand.models.hand import HandModel, load_hand
from wholehand.models.hand_config import HandConfig, parse_hand_config
from wholehand.models.hand_folders import resolve_hand_config
from wholehand.models.hand_report import HandReport
from wholehand.models.kinematics import HandKinematics
from wholehand.models.model_findings import (
    FEW_SAMPLES,
    add_roles,
    inertia_findings,
    palm_findings,
)
from wholehand.models.poses import rotation_angle

FloatArray = npt.NDArray[np.float64]

POSE_MISMATCH_M = 1e-6
"""Largest distance between a link's simulated and modelled pose accepted by the check [m]."""
POSE_MISMATCH_DEG = 1e-4
"""Largest angle between a link's simulated and modelled orientation [deg]."""
PLACEHOLDER_EFFORT = 50.0
"""A URDF effort limit above this [N*m or N] on a hand joint is taken for a placeholder."""
FAR_FROM_LINK = 0.3
"""A link's geometry whose bounding-box centre lies farther than this from the link frame, or
which spans more than this, is reported (wrong origin, or a mesh in millimetres) [m]."""


def _raw_joint_findings(cfg: HandConfig, report: HandReport) -> None:
    """What a URDF's joint tags say that Pinocchio accepts silently."""
    if cfg.model_format != "urdf":
        return
    root = ET.parse(cfg.model_path).getroot()
    placeholders: list[str] = []
    efforts: list[str] = []
    zero: list[str] = []
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
        if effort <= 0.0 and name not in cfg.locked_joints:
            zero.append(name)
        elif effort > PLACEHOLDER_EFFORT and name not in cfg.locked_joints:
            placeholders.append(f"{name} ({effort:g})")
        elif 0.0 < effort != cfg.torque_limit_default and name not in cfg.locked_joints:
            efforts.append(f"{name} ({effort:g})")
    _effort_findings(cfg, report, zero, efforts, placeholders)


def _effort_findings(
    cfg: HandConfig,
    report: HandReport,
    zero: list[str],
    efforts: list[str],
    placeholders: list[str],
) -> None:
    """What the URDF's efforts of the joints in ``zero`` (zero), ``efforts`` (real-looking, not
    used) and ``placeholders`` (too large to be real) mean for the torque limits."""
    unset = [j for j in zero if j not in cfg.torque_limits]
    if unset:
        report.add(
            "warning",
            f'{len(unset)} joints have effort="0" in {cfg.model_path.name}: {unset[:6]}'
            f"{' ...' if len(unset) > 6 else ''}; wholehand gives them the default torque "
            f"limit {cfg.torque_limit_default:g} N*m without a word, and a simulator or driver "
            "that reads the URDF gives them none",
            "set each motor's effort [N*m] in the URDF from the data sheet, or its [joints] "
            "torque_limit in hand.toml",
        )
    if efforts and not cfg.torque_limit_set:
        report.add(
            "warning",
            f"{len(efforts)} joints have URDF effort limits [N*m] that wholehand does not use: "
            f"{', '.join(efforts[:4])}{' ...' if len(efforts) > 4 else ''}; hand.toml sets no "
            f"[joints] torque_limit, so every motor gets the default "
            f"{cfg.torque_limit_default:g} N*m",
            "set [joints] torque_limit in hand.toml to the motors' limits (the URDF's efforts "
            "if they are the real ones)",
        )
    if placeholders and not cfg.torque_limit_set:
        report.add(
            "warning",
            f"{len(placeholders)} joints have URDF effort limits that look like placeholders: "
            f"{', '.join(placeholders[:4])}{' ...' if len(placeholders) > 4 else ''}; wholehand "
            f"ignores them and uses [joints] torque_limit (default {cfg.torque_limit_default:g})",
            "set [joints] torque_limit in hand.toml to the motors' real limits [N*m]",
        )


COUPLING_SLACK = 0.01
"""How far [rad or m] a coupling may drive its follower past the follower's limits before
``hand check`` flags it: URDFs round multipliers (the Inspire hand's 1.334 x 0.6 = 0.8004
against a limit of 0.8), and such an overshoot is of no consequence."""


def _coupling_findings(hand: HandModel, report: HandReport) -> None:
    """A follower that its coupling drives past its own limits (by more than
    :data:`COUPLING_SLACK`) within its leader's range."""
    model = hand.model
    for follower, mimic in hand.mimics.items():
        f = model.joints[model.getJointId(follower)].idx_q
        lead = model.joints[model.getJointId(mimic.leader)].idx_q
        ends = mimic.multiplier * np.array([hand.q_lower[lead], hand.q_upper[lead]])
        ends += mimic.offset
        lo, hi = float(ends.min()), float(ends.max())
        past = max(hand.q_lower[f] - lo, hi - hand.q_upper[f])
        if past > COUPLING_SLACK:
            report.add(
                "warning",
                f"joint {follower!r} follows {mimic.leader!r} as {mimic.multiplier:g} x "
                f"{mimic.leader} + {mimic.offset:g}, which spans [{lo:.3f}, {hi:.3f}] rad over "
                f"the leader's range, past its own limits [{hand.q_lower[f]:.3f}, "
                f"{hand.q_upper[f]:.3f}] by {past:.3f}",
                "check the multiplier and offset of the coupling, or the limits of both joints",
            )


def _close_torque_findings(hand: HandModel, report: HandReport) -> None:
    """Closing torques of a grasp style above their joint's torque limit (they get clamped)."""
    model = hand.model
    for style in hand.config.grasp_styles.values():
        table = "[grasping]" if style.name == "power" else f"[grasping.{style.name}]"
        for name, torque in style.close_torque.items():
            limit = float(hand.tau_max[model.joints[model.getJointId(name)].idx_v])
            if abs(torque) > limit:
                report.add(
                    "warning",
                    f"{table} close_torque of {name!r} is {abs(torque):g} N*m, above its torque "
                    f"limit {limit:g} N*m: the generator's closing is clamped to the limit",
                    f"lower it in {table}, or raise [joints] torque_limit for {name!r}",
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
                "multiplier": None if mimic is None else mimic.multiplier,
                "offset": None if mimic is None else mimic.offset,
            }
        )
    add_roles(hand, report)
    _coupling_findings(hand, report)
    _close_torque_findings(hand, report)
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
    palm_findings(hand, report)
    inertia_findings(hand, report)
    _simulation_findings(hand, report)
    return report


def _simulation_findings(hand: HandModel, report: HandReport) -> None:
    """The simulated hand (MuJoCo's scene) against the kinematic model (Pinocchio): every link
    where the model puts it, at the mid-range configuration and a quarter of the way in from
    either end of every joint's range."""
    from wholehand import registry
    from wholehand.models.objects import ObjectModel

    backend: Any
    try:
        backend = registry.load(
            "backends", "mujoco", hand=hand, obj=ObjectModel.sphere(0.02, mass=0.05)
        )
    except WholehandError as err:
        report.add("error", f"the MuJoCo scene does not build: {err}", "fix what the message names")
        return
    kin = HandKinematics(hand)
    finite = np.isfinite(hand.q_lower) & np.isfinite(hand.q_upper)
    lower = np.where(finite, hand.q_lower, 0.0)
    upper = np.where(finite, hand.q_upper, 0.0)
    shares = (0.5, 0.25, 0.75)
    worst: tuple[float, float, str, float] | None = None  # offset, angle, link, share
    largest = [0.0, 0.0]  # [m], [deg]
    for share in shares:
        q = hand.couple(np.where(finite, lower + share * (upper - lower), hand.neutral()))
        simulated = backend.link_poses(q)
        kin.update(q, hand.wMb)
        for i, link in enumerate(hand.link_names):
            model = kin.frame_pose(link)
            offset = float(np.linalg.norm(simulated[i, :3, 3] - model[:3, 3]))
            angle = float(np.degrees(rotation_angle(simulated[i, :3, :3], model[:3, :3])))
            largest = [max(largest[0], offset), max(largest[1], angle)]
            bad = offset > POSE_MISMATCH_M or angle > POSE_MISMATCH_DEG
            if bad and (worst is None or offset > worst[0]):
                worst = (offset, angle, link, share)
    report.summary["mujoco_vs_pinocchio"] = {
        "links": len(hand.link_names),
        "configurations": len(shares),
        "max_offset_mm": 1e3 * largest[0],
        "max_angle_deg": largest[1],
    }
    if worst is not None:
        offset, angle, link, share = worst
        report.add(
            "error",
            f"MuJoCo puts link {link!r} {1e3 * offset:.1f} mm and {angle:.1f} deg away "
            f"from where the kinematic model (Pinocchio) puts it, with the joints "
            f"{share:.0%} of the way through their ranges: the simulation would not be "
            "the hand the controller models",
            "check the URDF's root link (a root named 'world' is handled; other names "
            "MuJoCo reserves are not), its fixed joints and their origins",
        )
