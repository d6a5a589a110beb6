"""``wholehand run``: one stored grasp through the perturbation protocol, with numbers printed."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from wholehand.errors import ConfigError
from wholehand.loop.record import RunRecord
from wholehand.trials.outcome import STRICT_SLIP_DEG, STRICT_SLIP_MM, outcome_of

if TYPE_CHECKING:
    from wholehand.backends.table import Table
    from wholehand.loop.control_loop import Cycle, Observer
    from wholehand.models.objects import ObjectModel
    from wholehand.trials.trial import TrialSpec


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run",
        help="hold a stored grasp in MuJoCo through the paper's perturbation protocol",
        description="Runs one grasp (a stored one of the hand, or one of a file from anywhere "
        "with --grasps, e.g. from `wholehand grasps generate` or `grasps import`) through "
        "settle, six-direction load test, a rotational pull by theta about a random axis, and "
        "the load test again; prints per-stage results and timings.",
    )
    p.add_argument("--hand", default="allegro_right", help="shipped hand name or hand folder")
    p.add_argument(
        "--object", default=None, help="object (default: 077_rubiks_cube, or the --grasps file's)"
    )
    p.add_argument("--grasp", type=int, default=0, help="index into the object's grasp file")
    p.add_argument(
        "--grasps",
        default=None,
        metavar="FILE",
        help="take the grasp from this grasp file (default: the hand's stored grasps)",
    )
    p.add_argument(
        "--grasp-type", default="power", help="grasp file: power (default) or e.g. precision"
    )
    p.add_argument("--estimator", default="mesh_sdf", help="contact-estimator plug-in")
    p.add_argument("--allocator", default="qp", help="allocator plug-in")
    p.add_argument(
        "--protocol",
        choices=("paper", "dexgraspbench"),
        default="paper",
        help="paper: settle, load test, pull, load test (default); dexgraspbench: "
        "DexGraspBench's load test (0.1 kg, mu 0.6, six 1 N pushes of 2 s, fail at 5 cm or "
        "15 deg; the allocator is told mu = 0.6)",
    )
    p.add_argument("--theta", type=float, default=60.0, help="rotation of the pull [deg]")
    p.add_argument("--seed", type=int, default=0, help="seeds the pull's rotation axis")
    p.add_argument("--rate", type=float, default=200.0, help="control rate in sim time [Hz]")
    p.add_argument("--k", type=int, default=None, help="contacts per link (default 5)")
    p.add_argument(
        "--d-thresh", type=float, default=None, help="contact threshold [m] (default 0.01)"
    )
    p.add_argument(
        "--hysteresis",
        type=float,
        default=None,
        metavar="M",
        help="mesh_sdf: how much closer [m] a new sample must be to displace a contact a link "
        "kept last cycle (default 0.001; 0: the paper's selection)",
    )
    p.add_argument("--gravity", action="store_true", help="turn gravity on (off in the paper)")
    p.add_argument(
        "--sdf-spacing",
        default=None,
        help="object SDF node spacing [m], or 'auto' to resolve its thinnest wall "
        "(default 0.002; see docs/reliability.md)",
    )
    g = p.add_argument_group(
        "object tracking",
        "how the object pose reaches the controller (default: exact, every cycle)",
    )
    g.add_argument("--pose-rate", type=float, default=None, help="tracker frame rate [Hz]")
    g.add_argument(
        "--pose-latency", type=float, default=None, help="delay of each frame [s] (e.g. 0.033)"
    )
    g.add_argument("--pose-noise-mm", type=float, default=0.0, help="noise per axis [mm]")
    g.add_argument("--pose-noise-deg", type=float, default=0.0, help="rotation noise [deg]")
    g.add_argument(
        "--pose-dropout",
        action="append",
        default=[],
        metavar="START:DURATION",
        help="no new pose from START for DURATION [s] (repeatable)",
    )
    g.add_argument(
        "--estimate-at",
        choices=("object_stamp", "current"),
        default="object_stamp",
        help="estimate contacts at q(stamp of the pose) as in the paper, or at the current q",
    )
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
    p.add_argument(
        "--record",
        default=None,
        metavar="RUN.mcap",
        help="write the run as an MCAP file of ROS 2 messages (Foxglove, ros2 bag play, "
        "`wholehand view`)",
    )
    p.add_argument("--plot", default=None, help="write the per-run PNG here")
    p.set_defaults(func=_cmd_run)


def tracking_options(args: argparse.Namespace) -> dict[str, Any]:
    """``TrialSpec.tracking`` from the command line (errors name the option)."""
    out: dict[str, Any] = {}
    for option, key, value in (
        ("--pose-rate", "rate_hz", args.pose_rate),
        ("--pose-latency", "latency_s", args.pose_latency),
    ):
        if value is not None:
            if not (math.isfinite(value) and value >= 0.0 and (value > 0 or key != "rate_hz")):
                raise ConfigError(f"{option} {value} is invalid")
            out[key] = value
    for option, key, value in (
        ("--pose-noise-mm", "noise_mm", args.pose_noise_mm),
        ("--pose-noise-deg", "noise_deg", args.pose_noise_deg),
    ):
        if not (math.isfinite(value) and value >= 0.0):
            raise ConfigError(f"{option} {value} must be finite and >= 0")
        if value:
            out[key] = value
    if out.get("noise_mm") or out.get("noise_deg"):
        out["noise_seed"] = args.seed
    dropouts = [_dropout(text) for text in args.pose_dropout]
    if dropouts:
        out["dropouts"] = dropouts
    return out


def _dropout(text: str) -> list[float]:
    """``--pose-dropout START:DURATION`` as [start, duration] [s]."""
    try:
        start, duration = (float(x) for x in text.split(":"))
    except ValueError:
        raise ConfigError(f"--pose-dropout {text!r} must be START:DURATION in seconds") from None
    return [start, duration]


def _object(name: str, sdf_spacing: str | None) -> ObjectModel | None:
    """The object with ``--sdf-spacing`` applied (None: the trial loads it as registered)."""
    if sdf_spacing is None:
        return None
    from wholehand.models.object_catalogue import load_object
    from wholehand.models.objects import AUTO_SPACING

    if sdf_spacing == AUTO_SPACING:
        return load_object(name, sdf_spacing=AUTO_SPACING)
    try:
        spacing = float(sdf_spacing)
    except ValueError:
        raise ConfigError(
            f"--sdf-spacing {sdf_spacing!r} must be a spacing in metres (e.g. 0.001) or "
            f"{AUTO_SPACING!r}"
        ) from None
    return load_object(name, sdf_spacing=spacing)


def _cmd_run(args: argparse.Namespace) -> int:
    from wholehand.trials.trial import run_trial

    spec = _trial_spec(args)
    observers = [live_view(spec, args.view_every)] if args.view else []
    recorder = None
    if args.record:
        from wholehand.recording.mcap_recording import McapRecorder

        recorder = McapRecorder(args.record, {"spec": dataclasses.asdict(spec)})
        observers.append(recorder)
    if args.protocol == "dexgraspbench":
        return _load_test(args, spec, observers)
    record = run_trial(spec, obj=_object(spec.object, args.sdf_spacing), observers=observers)
    _write_outputs(args, record)
    if recorder is not None:
        print(recorder.report())
    summary = summarise(record)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print_summary(summary)
    loop = record.meta["loop"]
    if loop["n_errors"]:
        first = loop["errors"][0]
        print(
            f"\nERROR: stage {first['stage']!r} raised {loop['n_errors']} times (first at t = "
            f"{first['t']:.3f} s); the last feasible torque was kept each time:\n"
            f"{first['traceback']}",
            file=sys.stderr,
        )
        return 1
    return 0


def _trial_spec(args: argparse.Namespace) -> TrialSpec:
    """The trial ``wholehand run``'s options describe.

    Raises:
        ConfigError: a bad angle or rate, or --grasps of another object than --object.
    """
    from wholehand.trials.trial import TrialSpec

    if not (math.isfinite(args.theta) and args.theta >= 0.0):
        raise ConfigError(f"--theta {args.theta} must be a finite angle >= 0 [deg]")
    if not (math.isfinite(args.rate) and args.rate > 0.0):
        raise ConfigError(f"--rate {args.rate} must be a finite rate > 0 [Hz]")
    est_params = {
        k: v
        for k, v in {"k": args.k, "d_thresh": args.d_thresh, "hysteresis": args.hysteresis}.items()
        if v is not None
    }
    obj = args.object or "077_rubiks_cube"
    if args.grasps:
        from wholehand.grasps.store import grasp_file_object

        obj = grasp_file_object(args.grasps)
        if args.object and args.object != obj:
            raise ConfigError(
                f"--grasps {args.grasps} holds grasps of {obj!r}, not of --object {args.object!r}"
            )
    return TrialSpec(
        hand=args.hand,
        object=obj,
        grasp=args.grasp,
        grasp_type=args.grasp_type,
        grasp_file=str(Path(args.grasps).resolve()) if args.grasps else "",
        estimator=args.estimator,
        allocator=args.allocator,
        theta_deg=args.theta,
        seed=args.seed,
        control_rate=args.rate,
        gravity=args.gravity,
        estimator_params=est_params,
        backend_params={"self_collision": False} if args.no_self_collision else {},
        tracking=tracking_options(args),
        estimate_at=args.estimate_at,
    )


def _write_outputs(args: argparse.Namespace, record: RunRecord) -> None:
    """Save the run, its HTML animation and its plot where the options ask."""
    if args.save:
        print(f"run record: {record.save(Path(args.save))}")
    if args.record_html:
        from wholehand.viz.replay import write_html

        print(f"html: {write_html(record, args.record_html)}")
    if args.plot:
        from wholehand.viz.plots import plot_run

        print(f"plot: {plot_run(record, args.plot)}")


def _load_test(args: argparse.Namespace, spec: Any, observers: list[Observer]) -> int:
    """``--protocol dexgraspbench``: run DexGraspBench's load test and print it."""
    import dataclasses

    from wholehand.models.hand import load_hand
    from wholehand.trials.dexgraspbench import FRICTION, run_load_test

    for flag in ("save", "record_html", "plot", "record"):
        if getattr(args, flag):
            raise ConfigError(
                f"--{flag.replace('_', '-')} records one run of the paper's protocol; "
                "--protocol dexgraspbench runs one per direction: leave it out"
            )
    spec = dataclasses.replace(spec, allocator_params={"mu": FRICTION, **spec.allocator_params})
    from wholehand.models.object_catalogue import load_object

    obj = _object(spec.object, args.sdf_spacing) or load_object(spec.object)
    out = run_load_test(spec, load_hand(spec.hand), obj, observers)
    if args.json:
        print(json.dumps(out, indent=2, default=lambda o: o.__dict__))
        return 0
    print(
        f"DexGraspBench load test: {spec.hand}, {spec.object} grasp {spec.grasp}, "
        f"{spec.allocator} (gravity off, 0.1 kg, mu 0.6, 1 N for 2 s per direction)\n"
    )
    print("  direction  passed  moved [mm]  turned [deg]  failed in")
    for d in out["directions"]:
        print(
            f"  {d.direction:9s}  {'yes' if d.passed else 'no':6s}  {1000 * d.translation:10.1f}"
            f"  {d.rotation_deg:12.1f}  {d.failed_in or '-'}"
        )
    print(f"\nheld: {'yes' if out['held'] else 'no'}  (wall time {out['wall_time_s']:.1f} s)")
    return 0


def live_view(spec: Any, every: int, table: Table | None = None) -> Observer:
    """A loop observer drawing every ``every``-th cycle in a live meshcat viewer (true object
    pose, the contacts and forces the controller used), and ``table`` if given."""
    from wholehand.loop.control_loop import Observer
    from wholehand.models.hand import load_hand
    from wholehand.models.object_catalogue import load_object
    from wholehand.viz.scene import SceneViewer, scene_points

    hand, obj = load_hand(spec.hand), load_object(spec.object)
    viewer = SceneViewer.live(hand, obj)
    if table is not None:
        viewer.draw_table(table)

    class LiveView(Observer):
        def on_cycle(self, cycle: Cycle) -> str | None:
            truth, out = cycle.truth, cycle.output
            if cycle.index % max(1, every) or truth.wMo is None:
                return None
            if cycle.index == 0:
                radius = 0.5 * float(np.linalg.norm(obj.mesh.extents))
                states = [(truth.q, truth.wMb)]
                viewer.frame(scene_points(hand, states, [(truth.wMo[:3, 3], radius)]))
            p = _NONE if out.contacts is None else out.contacts.p_world
            f = _NONE if out.allocation is None else out.allocation.f_world
            viewer.update(truth.q, truth.wMo, p, f, truth.wMb)
            return None

    return LiveView()


_NONE = np.zeros((0, 3))


def summarise(record: RunRecord) -> dict[str, object]:
    """Per-phase results, faults, timing and the verdict of a run, JSON-serialisable."""
    meta = record.meta
    outcome = outcome_of(record)
    wall = float(meta.get("wall_time_s", float("nan")))
    loop = meta.get("loop", {})
    return {
        "spec": meta.get("spec"),
        "held": outcome.held,
        "held_strict": outcome.held_strict,
        "slip_mm": outcome.slip_mm,
        "slip_deg": outcome.slip_deg,
        "failure_phase": outcome.failure_phase,
        "error": outcome.error,
        "phases": record.phase_summary(),
        "faults": loop.get("faults", {}),
        "unbalanced_cycles": outcome.unbalanced_cycles,
        "clamped_cycles": loop.get("clamped", 0),
        "last_fault": loop.get("last_fault", ""),
        "held_commands": loop.get("held_commands", 0),
        "longest_hold": {
            "cycles": loop.get("longest_hold", 0),
            "s": loop.get("longest_hold_s", 0.0),
            "at_s": loop.get("longest_hold_at", 0.0),
            "status": loop.get("longest_hold_status", ""),
        },
        "timing": {
            **record.timing_summary(),
            "cycles": outcome.cycles,
            "sim_time_s": meta.get("sim_time_s"),
            "wall_time_s": wall,
            "control_rate_hz": meta.get("control_rate"),
        },
    }


def print_summary(summary: dict[str, Any]) -> None:
    spec = summary["spec"]
    print(
        f"{spec['hand']} holding {spec['object']} ({spec['grasp_type']} grasp {spec['grasp']}), "
        f"{spec['estimator']} + {spec['allocator']}, theta = {spec['theta_deg']:g} deg, "
        f"seed {spec['seed']}"
    )
    header = (
        f"{'phase':<10} {'held':<5} {'contacts':>8} {'|f_res| N':>10} {'|t_res| Nmm':>11} "
        f"{'disp mm':>8} {'rot deg':>8}"
    )
    print(header)
    print("-" * len(header))
    for s in summary["phases"]:
        if s.get("held") is None:
            print(f"{s['phase']:<10} {'-':<5} (not reached)")
            continue
        print(
            f"{s['phase']:<10} {'yes' if s['held'] else 'LOST':<5} {s['contacts_mean']:>8.1f} "
            f"{s['residual_force_N']:>10.3f} {1e3 * s['residual_torque_Nm']:>11.2f} "
            f"{s['displacement_mm']:>8.1f} {s['rotation_deg']:>8.1f}"
        )
    t = summary["timing"]
    strict = (
        f"strict: {'held' if summary['held_strict'] else 'NOT held'} (the object ended "
        f"{summary['slip_mm']:.1f} mm and {summary['slip_deg']:.1f} deg from where the hand "
        f"held it after settling; bounds {STRICT_SLIP_MM:g} mm, {STRICT_SLIP_DEG:g} deg)"
    )
    print(
        f"\nresult: {'HELD through every phase' if summary['held'] else 'LOST'} (the paper's "
        f"criterion)\n{strict}\n"
        f"QP time        p50 {t['qp_p50_us']:8.0f} us   p99 {t['qp_p99_us']:8.0f} us\n"
        f"estimate time  p50 {t['estimate_p50_us']:8.0f} us   p99 {t['estimate_p99_us']:8.0f} us\n"
        f"cycle time     p50 {t['cycle_p50_us']:8.0f} us   p99 {t['cycle_p99_us']:8.0f} us"
        f"   -> {t['achievable_rate_hz']:.0f} Hz achievable "
        f"(run at {t['control_rate_hz']:g} Hz sim time)\n"
        f"{t['cycles']} cycles, {t['sim_time_s']:.2f} s simulated "
        f"in {t['wall_time_s']:.1f} s wall time"
    )
    if summary["unbalanced_cycles"]:
        print(
            f"unbalanced: {summary['unbalanced_cycles']} cycles whose allocated forces do not "
            "balance the object (residual above the tolerance of wholehand/defaults.py; their "
            "torques, within the limits, were applied)"
        )
    if summary["clamped_cycles"]:
        print(f"clamped: {summary['clamped_cycles']} commands exceeded a torque limit")
    if summary["faults"]:
        counts = ", ".join(f"{n} {status}" for status, n in summary["faults"].items())
        print(f"faulted cycles: {counts} (last: {summary['last_fault']})")
    hold = summary["longest_hold"]
    if hold["cycles"]:
        print(
            f"held torque: {summary['held_commands']} cycles kept the last feasible torque; "
            f"the longest hold {hold['cycles']} cycles ({1e3 * hold['s']:.0f} ms) from "
            f"t = {hold['at_s']:.3f} s ({hold['status']} first)"
        )
