"""``wholehand run``: one stored grasp through the perturbation protocol, with numbers printed."""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from wholehand.loop.record import RunRecord


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run",
        help="hold a stored grasp in MuJoCo through the paper's perturbation protocol",
        description="Runs one shipped grasp through settle, six-direction load test, a rotational "
        "pull by theta about a random axis, and the load test again; prints per-stage results "
        "and timings.",
    )
    p.add_argument("--hand", default="allegro_right")
    p.add_argument("--object", default="077_rubiks_cube")
    p.add_argument("--grasp", type=int, default=0, help="index into the object's grasp file")
    p.add_argument(
        "--grasp-type", default="power", help="grasp file: power (default) or e.g. precision"
    )
    p.add_argument("--estimator", default="mesh_sdf", help="contact-estimator plug-in")
    p.add_argument("--allocator", default="qp", help="allocator plug-in")
    p.add_argument("--theta", type=float, default=60.0, help="rotation of the pull [deg]")
    p.add_argument("--seed", type=int, default=0, help="seeds the pull's rotation axis")
    p.add_argument("--rate", type=float, default=200.0, help="control rate in sim time [Hz]")
    p.add_argument("--k", type=int, default=None, help="contacts per link (default 5)")
    p.add_argument(
        "--d-thresh", type=float, default=None, help="contact threshold [m] (default 0.01)"
    )
    p.add_argument("--gravity", action="store_true", help="turn gravity on (off in the paper)")
    p.add_argument(
        "--no-self-collision",
        action="store_true",
        help="MuJoCo: hand links do not collide with each other (they do by default)",
    )
    p.add_argument("--save", default=None, help="write the run record (.npz) here")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument(
        "--view", action="store_true", help="show the run live in meshcat (prints the URL)"
    )
    p.add_argument("--view-every", type=int, default=8, help="--view: draw every n-th cycle")
    p.add_argument("--record-html", default=None, help="write a standalone HTML animation here")
    p.add_argument("--plot", default=None, help="write the per-run PNG here")
    p.set_defaults(func=_cmd_run)


def _cmd_run(args: argparse.Namespace) -> int:
    from wholehand.loop.trial import TrialSpec, run_trial

    est_params = {
        k: v for k, v in {"k": args.k, "d_thresh": args.d_thresh}.items() if v is not None
    }
    spec = TrialSpec(
        hand=args.hand,
        object=args.object,
        grasp=args.grasp,
        grasp_type=args.grasp_type,
        estimator=args.estimator,
        allocator=args.allocator,
        theta_deg=args.theta,
        seed=args.seed,
        control_rate=args.rate,
        gravity=args.gravity,
        estimator_params=est_params,
        backend_params={"self_collision": False} if args.no_self_collision else {},
    )
    on_cycle = live_view_callback(spec, args.view_every) if args.view else None
    record = run_trial(spec, on_cycle=on_cycle)
    if args.save:
        print(f"run record: {record.save(Path(args.save))}")
    if args.record_html:
        from wholehand.viz.replay import write_html

        print(f"html: {write_html(record, args.record_html)}")
    if args.plot:
        from wholehand.viz.plots import plot_run

        print(f"plot: {plot_run(record, args.plot)}")
    summary = summarise(record)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print_summary(summary)
    return 0


def live_view_callback(spec: object, every: int) -> Callable[[int, Any, Any], None]:
    """A per-cycle callback drawing every ``every``-th cycle in a live meshcat viewer."""
    from wholehand.models.hand import load_hand
    from wholehand.models.objects import load_object
    from wholehand.viz.scene import SceneViewer

    hand, obj = load_hand(spec.hand), load_object(spec.object)  # type: ignore[attr-defined]
    viewer = SceneViewer.live(hand, obj)
    started: list[bool] = []

    def draw(i: int, state: Any, cycle: Any) -> None:
        if i % max(1, every):
            return
        if not started:
            viewer.set_camera(state.wMo[:3, 3])
            started.append(True)
        f_world = cycle.allocation.f_world
        viewer.update(state.q, state.wMo, cycle.contacts.p_world, f_world, state.wMb)

    return draw


def summarise(record: RunRecord) -> dict[str, object]:
    """Per-stage results, timing and the verdict of a run, JSON-serialisable."""
    meta = record.meta
    cycles = int(record.arrays()["t"].size)
    wall = float(meta.get("wall_time_s", float("nan")))
    return {
        "spec": meta.get("spec"),
        "held": record.held_throughout
        and len(record.stage_summary()) == len(record.stages)
        and all(s["held"] for s in record.stage_summary()),
        "stages": record.stage_summary(),
        "timing": {
            **record.timing_summary(),
            "cycles": cycles,
            "sim_time_s": meta.get("sim_time_s"),
            "wall_time_s": wall,
            "control_rate_hz": meta.get("control_rate"),
        },
    }


def print_summary(summary: dict[str, object]) -> None:
    spec = summary["spec"]
    print(
        f"{spec['hand']} holding {spec['object']} ({spec['grasp_type']} grasp {spec['grasp']}), "
        f"{spec['estimator']} + {spec['allocator']}, theta = {spec['theta_deg']:g} deg, "
        f"seed {spec['seed']}"
    )
    header = (
        f"{'stage':<10} {'held':<5} {'contacts':>8} {'|f_res| N':>10} {'|t_res| Nmm':>11} "
        f"{'disp mm':>8} {'rot deg':>8}"
    )
    print(header)
    print("-" * len(header))
    for s in summary["stages"]:
        if s.get("held") is None:
            print(f"{s['stage']:<10} {'-':<5} (not reached)")
            continue
        print(
            f"{s['stage']:<10} {'yes' if s['held'] else 'LOST':<5} {s['contacts_mean']:>8.1f} "
            f"{s['residual_force_N']:>10.3f} {1e3 * s['residual_torque_Nm']:>11.2f} "
            f"{s['displacement_mm']:>8.1f} {s['rotation_deg']:>8.1f}"
        )
    t = summary["timing"]
    print(
        f"\nresult: {'HELD through every stage' if summary['held'] else 'LOST'}\n"
        f"QP time        p50 {t['qp_p50_us']:8.0f} us   p99 {t['qp_p99_us']:8.0f} us\n"
        f"estimate time  p50 {t['estimate_p50_us']:8.0f} us   p99 {t['estimate_p99_us']:8.0f} us\n"
        f"cycle time     p50 {t['cycle_p50_us']:8.0f} us   p99 {t['cycle_p99_us']:8.0f} us"
        f"   -> {t['achievable_rate_hz']:.0f} Hz achievable "
        f"(run at {t['control_rate_hz']:g} Hz sim time)\n"
        f"{t['cycles']} cycles, {t['sim_time_s']:.2f} s simulated "
        f"in {t['wall_time_s']:.1f} s wall time"
    )
