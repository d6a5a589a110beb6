"""``wholehand view``: replay a saved run record in meshcat, or write it as HTML / PNG."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from wholehand.loop.record import RunRecord


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "view",
        help="replay a run record (.npz from `wholehand run --save`, or an .mcap recording from "
        "--record) in meshcat or write files",
        description="With no output option, starts meshcat's local viewer (no network needed), "
        "prints its URL and plays the record. --html writes a standalone animation that opens "
        "offline; --plot writes the per-run PNG (contacts, residual wrench, torques, QP time).",
    )
    p.add_argument("record", help="run record (.npz) or recording (.mcap)")
    p.add_argument("--html", default=None, help="write a standalone HTML animation here")
    p.add_argument("--plot", default=None, help="write the per-run PNG here")
    p.add_argument(
        "--distance-colours",
        action="store_true",
        help="colour the hand's surface samples by distance to the nearest contact",
    )
    p.add_argument("--min-force", type=float, default=None, help="arrow threshold [N] (0.5)")
    p.add_argument("--fps", type=float, default=20.0, help="frames per second of sim time")
    p.add_argument("--speed", type=float, default=1.0, help="live replay speed (x sim time)")
    p.add_argument("--loop", action="store_true", help="live: replay until interrupted")
    p.set_defaults(func=_cmd_view)


def _read_record(path: Path) -> RunRecord:
    """The run record or MCAP recording at ``path``."""
    from wholehand.errors import ConfigError
    from wholehand.loop.record import RunRecord

    if not path.is_file():
        raise ConfigError(
            f"wholehand view: no run record at {path}; write one with `wholehand run --save` "
            "or `--record run.mcap`"
        )
    if path.suffix == ".mcap":
        import sys

        from wholehand.recording.mcap_replay import read_mcap_record

        record = read_mcap_record(path)
        if record.meta.get("cut_short"):
            print(f"warning: {record.meta['cut_short']}", file=sys.stderr)
        return record
    return RunRecord.load(path)


def _cmd_view(args: argparse.Namespace) -> int:
    from wholehand.errors import ConfigError

    record = _read_record(Path(args.record))
    try:
        return _show(args, record)
    except ConfigError as err:  # the hand or object the record names, say
        raise ConfigError(f"{args.record}: {err}") from err


def _show(args: argparse.Namespace, record: RunRecord) -> int:
    """Write the files the options ask for, or replay ``record`` live."""
    if args.plot:
        from wholehand.viz.plots import plot_run

        print(f"plot: {plot_run(record, args.plot)}")
    if args.html:
        from wholehand.viz.replay import write_html

        out = write_html(
            record,
            args.html,
            fps=args.fps,
            distance_colours=args.distance_colours,
            min_force=args.min_force,
        )
        print(f"html: {out}")
    if args.plot or args.html:
        return 0
    from wholehand.viz.arrows import FORCE_ARROW_MIN_N
    from wholehand.viz.replay import (
        load_models,
        record_colour_scale,
        record_scene_points,
        replay_live,
    )
    from wholehand.viz.scene import SceneViewer

    hand, obj = load_models(record)
    threshold = FORCE_ARROW_MIN_N if args.min_force is None else args.min_force
    viewer = SceneViewer.live(
        hand,
        obj,
        colour_scale=record_colour_scale(record, threshold),
        min_force=threshold,
        distance_colours=args.distance_colours,
    )
    if record.meta.get("table"):
        from wholehand.backends.table import Table

        viewer.draw_table(Table(**record.meta["table"]))
    if record.rows.get("p_object"):
        viewer.frame(record_scene_points(record, hand, obj))
    try:
        while True:
            replay_live(record, viewer, speed=args.speed, fps=args.fps)
            if not args.loop:
                break
    except KeyboardInterrupt:
        pass
    return 0
