"""``wholehand hand check DIR``: what a hand folder gives the controller, and what to fix."""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from wholehand.models.hand_report import HandReport


def add_parser(sub: argparse._SubParsersAction) -> None:
    hand = sub.add_parser("hand", help="check a hand folder")
    hsub = hand.add_subparsers(dest="hand_command", required=True)
    p = hsub.add_parser(
        "check",
        help="links, joints, actuators, couplings, limits, samples and findings with their fix",
        description="Loads a hand folder (hand.toml and its URDF) as the controller would and "
        "reports what it found; exits 1 when the hand cannot be used.",
    )
    p.add_argument("hand", help="hand folder, its hand.toml, or a shipped hand's name")
    p.add_argument("--png", default=None, help="write the surface samples, coloured by link")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=_cmd_check)


def _cmd_check(args: argparse.Namespace) -> int:
    from wholehand.models.check import check_hand
    from wholehand.models.hand_picture import plot_samples

    report = check_hand(args.hand)
    if args.png and report.hand is not None:
        print(f"samples: {plot_samples(report.hand, args.png)}")
    if args.json:
        print(json.dumps(report.as_dict(), indent=2))
        return 0 if report.ok else 1
    _print_model(report)
    print()
    if not report.findings:
        print("no findings")
    for f in report.findings:
        print(f"{f.severity.upper()}: {f.what}\n  fix: {f.fix}")
    print(f"\n{'usable' if report.ok else 'NOT usable'}: {len(report.findings)} findings")
    return 0 if report.ok else 1


def _print_model(report: HandReport) -> None:
    """The report's summary: the hand, its joints (limits, torque limits, actuation), locked
    joints and samples per link."""
    s = report.summary
    print(f"hand {s.get('name', '?')} from {report.path}")
    if s:
        print(
            f"  {s['nq']} joints, {s['actuated_dofs']} actuated; {s['links_with_geometry']} "
            f"contact links ({s['actuated_links']} actuated, {s['fingertip_links']} fingertips); "
            f"{s['candidate_points']} surface samples ({s['sample_surface']} geometry)"
        )
    if report.joints:
        print(
            f"\n  {'joint':<24} {'lower':>8} {'upper':>8}  {'torque limit':>12}  "
            f"{'actuation':<16} {'finger, role':<18} closes (model)"
        )
        for j in report.joints:
            if j["follows"]:
                how = f"follows {j['follows']} x {j['multiplier']:g} + {j['offset']:g}"
            else:
                how = "motor" if j["actuated"] else "arm (position)" if j["arm"] else "passive"
            role = f"{j['finger']}, {j['role']}" if j.get("role") else "-"
            derived = j.get("derived_close_torque")
            closes = "no" if derived is None else "+q" if derived > 0 else "-q"
            print(
                f"  {j['name']:<24} {j['lower']:>8.3f} {j['upper']:>8.3f}  "
                f"{j['torque_limit']:>12.3g}  {how:<16} {role:<18} {closes}"
            )
    if s.get("locked_joints"):
        print(f"  locked: {s['locked_joints']}")
    palm = s.get("palm_normal")
    if palm:
        used = "hand.toml's palm_normal" if palm["hand_toml"] else "the model's"
        angle = f", {palm['angle_deg']:.0f} deg apart" if "angle_deg" in palm else ""
        print(
            f"  palm normal (root frame): the fingers close toward {palm['model']}; hand.toml "
            f"gives {palm['hand_toml']}{angle}; {used} is used"
        )
    match = s.get("mujoco_vs_pinocchio")
    if match:
        print(
            f"  MuJoCo's and Pinocchio's poses of all {match['links']} links compared at "
            f"{match['configurations']} joint configurations: at most "
            f"{match['max_offset_mm']:.2g} mm and {match['max_angle_deg']:.2g} deg apart"
        )
    if s.get("points_per_link"):
        print("\n  samples per link:")
        for link, n in s["points_per_link"].items():
            print(f"    {link:<30} {n:>6}")
