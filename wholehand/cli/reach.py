"""``wholehand reach``: a seeded reach-grasp-hold-regrasp episode, with its timeline."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from wholehand.reaching.episode_spec import EpisodeSpec


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "reach",
        help="reach, grasp, hold and regrasp an object a person moves (MuJoCo, gravity on)",
        description="A seeded episode (wholehand/reaching/episode.py): the hand on a floating "
        "wrist reaches for an object a person holds and moves, regulates the grip once thumb "
        "and two fingers touch, is pushed and twisted, has the object snatched and regrasps it.",
    )
    p.add_argument("--hand", default="allegro_right", help="shipped hand name or hand folder")
    p.add_argument("--object", default="077_rubiks_cube", help="object with stored grasps")
    p.add_argument("--seed", type=int, default=0, help="seeds the perturbations and start pose")
    p.add_argument("--duration", type=float, default=14.0, help="longest episode [s]")
    p.add_argument(
        "--push", type=float, default=None, help="push while held [object weights] (default 1)"
    )
    p.add_argument(
        "--twist",
        type=float,
        default=None,
        help="twist while held [object weights at its rim: m g times half its largest side] (1)",
    )
    p.add_argument(
        "--no-balance-weight",
        action="store_true",
        help="the paper's quasi-static balance: the QP ignores the object's weight",
    )
    p.add_argument(
        "--no-gravity-compensation",
        action="store_true",
        help="the paper's tau = J^T f: the fingers do not hold their own links' weight",
    )
    p.add_argument(
        "--start",
        choices=("held", "table"),
        default="held",
        help="the object starts held out by a person (default) or resting on the table (needs "
        "the hand's table-top grasps: wholehand grasps generate --on-table)",
    )
    p.add_argument(
        "--self-collision",
        action="store_true",
        help="the reacher keeps the fingers apart (every pair of fingers' links 2 mm)",
    )
    p.add_argument("--reacher", default="mink", help="reacher plug-in")
    p.add_argument("--allocator", default="qp", help="allocator plug-in")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--save", default=None, help="write the summary (JSON) here")
    p.add_argument(
        "--record",
        default=None,
        metavar="RUN.npz|RUN.mcap",
        help="write the run here: .npz, wholehand's run record; .mcap, ROS 2 messages "
        "(Foxglove, ros2 bag play); both replay with `wholehand view`",
    )
    p.add_argument("--record-html", default=None, help="write a standalone HTML animation here")
    p.add_argument("--view", action="store_true", help="watch it live in meshcat (prints the URL)")
    p.add_argument("--view-every", type=int, default=8, help="--view: draw every n-th cycle")
    p.set_defaults(func=_cmd_reach)


def _cmd_reach(args: argparse.Namespace) -> int:
    from wholehand.reaching.episode import run_episode

    spec = _episode_spec(args)
    mcap = bool(args.record) and Path(args.record).suffix == ".mcap"
    recording = bool(args.record_html) or (bool(args.record) and not mcap)
    observers = _observers(args, spec, mcap)
    summary = run_episode(spec, record=recording, observers=observers)
    record = summary.pop("record", None)
    if mcap:
        print(observers[0].report())  # the recorder comes first
    elif args.record:
        print(f"run record: {record.save(Path(args.record))}")
    if args.record_html:
        from wholehand.viz.replay import write_html

        print(f"animation: {write_html(record, args.record_html)}")
    if args.save:
        path = Path(args.save)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(summary, indent=2, default=str))
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
    else:
        print(format_summary(summary))
    return 0


def _episode_spec(args: argparse.Namespace) -> EpisodeSpec:
    """The episode ``wholehand reach``'s options describe.

    Raises:
        ConfigError: a negative seed or a duration that is not > 0.
    """
    from wholehand.errors import ConfigError
    from wholehand.reaching.episode_spec import EpisodeSpec

    if args.seed < 0:
        raise ConfigError(f"--seed {args.seed} must be an integer >= 0")
    if not args.duration > 0.0:
        raise ConfigError(f"--duration {args.duration} must be > 0 [s]")
    extra = {k: getattr(args, k) for k in ("push", "twist") if getattr(args, k) is not None}
    return EpisodeSpec(
        hand=args.hand,
        object=args.object,
        seed=args.seed,
        duration=args.duration,
        reacher=args.reacher,
        allocator=args.allocator,
        balance_weight=not args.no_balance_weight,
        gravity_compensation=not args.no_gravity_compensation,
        self_collision=args.self_collision,
        start=args.start,
        **extra,
    )


def _observers(args: argparse.Namespace, spec: EpisodeSpec, mcap: bool) -> list[Any]:
    """The MCAP recorder and the live viewer, where the options ask for them."""
    if not (mcap or args.view):
        return []
    from dataclasses import asdict

    from wholehand.models.hand import load_hand
    from wholehand.reaching.episode import episode_table

    table = episode_table(load_hand(spec.hand))
    observers: list[Any] = []
    if mcap:
        from wholehand.recording.mcap_recording import McapRecorder

        observers.append(McapRecorder(args.record, {"spec": asdict(spec), "table": asdict(table)}))
    if args.view:
        from wholehand.cli.run import live_view

        observers.append(live_view(spec, args.view_every, table))
    return observers


def format_summary(s: dict[str, Any]) -> str:
    """The episode as a table like the paper's Table I plus its timeline."""
    spec = s["spec"]
    lines = [
        f"episode: {spec['hand']} holding {spec['object']}, seed {spec['seed']} "
        f"(MuJoCo, gravity on, {s.get('mount', 'floating wrist')}, table)",
        "",
        "  duration [s]  perturbations  grasps  losses  recovered  complete",
        f"  {s['duration_s']:12.2f}  {s['perturbations']:13d}  {s['grasps']:6d}  "
        f"{s['losses']:6d}  {s['recovered']:9d}  {'yes' if s['complete'] else 'no'}",
        "",
    ]
    skipped = s.get("skipped_perturbations", [])
    if skipped:
        lines += [f"not complete: left out because the hand held no object: {skipped}", ""]
    lines.append("timeline:")
    rows = [(e["t"], e["what"]) for e in s["events"]]
    rows += [(t["t"], f"{t['source']} -> {t['target']}: {t['reason']}") for t in s["transitions"]]
    rows += [(n["t"], f"{n['stage']}: {n['status']}: {n['reason']}") for n in s.get("notes", [])]
    lines += [f"  {t:7.3f} s  {what}" for t, what in sorted(rows, key=lambda r: r[0])]
    lines.append("")
    for kind, stats in s["cycle_us"].items():
        lines.append(f"{kind} cycle: p50 {stats['p50']:.0f} us, p99 {stats['p99']:.0f} us")
    if s["reacher_us"]:
        r = s["reacher_us"]
        lines.append(f"reacher step: p50 {r['p50']:.0f} us, p99 {r['p99']:.0f} us")
    if s.get("reacher_faults"):
        lines.append(f"reacher steps not taken as asked: {s['reacher_faults']}")
    warnings = {k: v for k, v in s["mujoco_warnings"].items() if v}
    if warnings:
        lines.append(f"MuJoCo warnings: {warnings}")
    return "\n".join(lines)
