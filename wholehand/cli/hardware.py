"""``wholehand control`` (the controller on a robot) and ``wholehand hw-sim`` (a robot double)."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

from wholehand.cli.arguments import (
    add_joint_gaps,
    joint_gaps,
    natural,
    positive_seconds,
    seconds,
)


def _config(args: argparse.Namespace) -> Any:
    from wholehand.ros2.config_file import hand_hardware_config, load_hardware_config

    config = load_hardware_config(args.config or hand_hardware_config(args.hand))
    connect = tuple(args.connect) if args.connect is not None else None
    listen = tuple(args.listen) if args.listen is not None else None
    config = config.with_endpoints(connect, listen)
    if args.transport is not None:
        config = replace(config, transport=args.transport)
    if args.dds_peer is not None:
        config = replace(config, dds_peers=tuple(args.dds_peer))
    if args.dds_interface is not None:
        config = replace(config, dds_interface=args.dds_interface)
    return config


def _recorders(args: argparse.Namespace, spec: object, distro: str) -> list[Any]:
    """The MCAP recorder of ``--record``, if given, in ``distro``'s message layout."""
    if not args.record:
        return []
    from dataclasses import asdict, is_dataclass

    from wholehand.recording.mcap_recording import McapRecorder

    info: dict[str, Any] = {"hand": args.hand, "object": args.object}
    if is_dataclass(spec) and not isinstance(spec, type):
        info["spec"] = asdict(spec)
    return [McapRecorder(args.record, info, distro)]


def _write(result: dict[str, Any], path: str | None, summary: dict[str, Any]) -> None:
    print(json.dumps(summary, indent=2))
    if path:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(json.dumps(result, indent=1))
        print(f"wrote {path}", file=sys.stderr)


def _cmd_control(args: argparse.Namespace) -> int:
    from wholehand.models.hand import load_hand
    from wholehand.models.object_catalogue import load_object
    from wholehand.robot.controller import ControllerSpec, run_controller

    spec = ControllerSpec(
        estimator=args.estimator,
        allocator=args.allocator,
        estimate_at=args.estimate_at,
        allocate_every=args.allocate_every,
        qp_deadline=args.qp_deadline or None,
        qp_deadline_after_miss=args.qp_deadline_after_miss,
        reacher=args.reacher,
    )
    config = _config(args)
    result = run_controller(
        load_hand(args.hand),
        load_object(args.object),
        config,
        spec,
        args.duration,
        trace=bool(args.json),
        announce=lambda line: print(line, file=sys.stderr, flush=True),
        observers=_recorders(args, spec, config.distro),
    )
    shown = {k: v for k, v in result.items() if k not in ("trace", "late_cycles")}
    shown["late_cycles"] = len(result["late_cycles"])  # each one's parts: the --json file
    _write(result, args.json, shown)
    return 0


def _cmd_hw_sim(args: argparse.Namespace) -> int:
    from wholehand.doubles.double import DoubleSpec, run_double
    from wholehand.models.hand import load_hand

    if load_hand(args.hand).arm_dofs.any():
        return _episode_double(args)

    params: dict[str, Any] = {}
    if args.quick:  # a shorter protocol: settle and a 0.3 s load per direction
        params = {"settle_time": 0.3, "load_duration": 0.3}
    if args.settle is not None:
        params["settle_time"] = args.settle
    spec = DoubleSpec(
        hand=args.hand,
        object=args.object,
        grasp=args.grasp,
        theta_deg=args.theta,
        seed=args.seed,
        latency=args.latency,
        noise_mm=args.noise_mm,
        noise_deg=args.noise_deg,
        dropouts=tuple((float(a), float(b)) for a, b in args.dropout or ()),
        joint_gaps=joint_gaps(args),
        pose_stamp=args.pose_stamp,
        command_timeout=args.command_timeout,
        gravity=args.gravity,
        protocol_params=params,
    )
    config = _config(args)
    summary, record = run_double(
        spec,
        config,
        args.wait,
        observers=_recorders(args, spec, config.distro),
        announce=lambda line: print(line, file=sys.stderr, flush=True),
    )
    if args.save:
        record.save(args.save)
    _write(summary, args.json, {k: v for k, v in summary.items() if k != "arrivals"})
    if summary["interrupted"]:
        print(f"hw-sim: stopped by a signal after {summary['cycles']} cycles", file=sys.stderr)
        return 130
    return 0 if summary["held"] else 1


def _episode_double(args: argparse.Namespace) -> int:
    from wholehand.doubles.episode_double import EpisodeDoubleSpec, run_episode_double
    from wholehand.reaching.episode_spec import EpisodeSpec

    episode = EpisodeSpec(
        hand=args.hand,
        object=args.object,
        seed=args.seed,
        duration=args.duration if args.duration is not None else EpisodeSpec.duration,
    )
    spec = EpisodeDoubleSpec(
        episode=episode,
        latency=args.latency,
        noise_mm=args.noise_mm,
        noise_deg=args.noise_deg,
        dropouts=tuple((float(a), float(b)) for a, b in args.dropout or ()),
        joint_gaps=joint_gaps(args),
        command_timeout=args.command_timeout,
        away=None if args.away is None else (float(args.away[0]), float(args.away[1])),
    )
    config = _config(args)
    summary = run_episode_double(
        spec,
        config,
        args.wait,
        _recorders(args, spec, config.distro),
        announce=lambda line: print(line, file=sys.stderr, flush=True),
    )
    _write(summary, args.json, summary)
    if summary["interrupted"]:
        print(f"hw-sim: stopped by a signal after {summary['cycles']} cycles", file=sys.stderr)
        return 130
    return 0


def _endpoints(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--config",
        help="hardware config TOML (default: ros2.toml in the hand's folder; docs/hardware.md)",
    )
    p.add_argument(
        "--transport",
        choices=("zenoh", "dds"),
        help="zenoh (robots on rmw_zenoh) or dds (a stock ROS 2 install: rmw_cyclonedds, "
        "rmw_fastrtps); overrides [ros2] transport",
    )
    p.add_argument("--connect", nargs="*", help="zenoh endpoints to connect to (overrides config)")
    p.add_argument("--listen", nargs="*", help="zenoh endpoints to listen on (overrides config)")
    p.add_argument(
        "--dds-peer",
        action="append",
        metavar="ADDRESS",
        help="DDS unicast discovery peer, repeatable (multicast off; overrides [ros2] dds_peers; "
        "127.0.0.1 for a double on this machine)",
    )
    p.add_argument(
        "--dds-interface",
        metavar="NAME_OR_ADDRESS",
        help="DDS network interface (overrides [ros2] dds_interface)",
    )
    p.add_argument("--hand", default="allegro_right", help="shipped hand name or hand folder")
    p.add_argument("--object", default="077_rubiks_cube", help="the grasped object")
    p.add_argument("--json", help="write the full result (with timings) to this JSON file")
    p.add_argument(
        "--record",
        metavar="RUN.mcap",
        help="record every cycle as an MCAP file of ROS 2 messages (Foxglove, ros2 bag play, "
        "`wholehand view`)",
    )


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "control",
        help="the controller on a robot over ROS 2 messages (zenoh or DDS; docs/hardware.md): "
        "the whole pipeline on an arm-hand, force regulation of a held grasp on a hand alone",
    )
    _endpoints(p)
    p.add_argument(
        "--duration", type=positive_seconds, help="stop after this many seconds (default: never)"
    )
    p.add_argument("--estimator", default="mesh_sdf")
    p.add_argument("--allocator", default="qp")
    p.add_argument("--reacher", default="mink", help="reacher plug-in (an arm-hand's pipeline)")
    p.add_argument(
        "--estimate-at",
        default="object_stamp",
        choices=["object_stamp", "current"],
        help="joint configuration the contacts of a pose are estimated at",
    )
    p.add_argument(
        "--allocate-every",
        default="cycle",
        choices=["cycle", "pose"],
        help="allocate every control cycle or once per object pose",
    )
    p.add_argument(
        "--qp-deadline",
        type=seconds,
        default=0.002,
        help="time budget of one allocation [s] (0: none); past it the last feasible "
        "torque is kept",
    )
    p.add_argument(
        "--qp-deadline-after-miss",
        type=positive_seconds,
        help="time budget of an allocation right after a missed one [s], at least "
        "--qp-deadline (default: 1.5 times it)",
    )
    p.set_defaults(func=_cmd_control)

    p = sub.add_parser(
        "hw-sim",
        help="play a robot over ROS 2 messages: MuJoCo in real time, a tracker with latency; "
        "an arm-hand plays the reach episode with its person, a hand alone a held grasp",
    )
    _endpoints(p)
    p.add_argument(
        "--duration",
        type=positive_seconds,
        help="arm-hand: longest episode [s] (default: the episode's)",
    )
    p.add_argument(
        "--away",
        nargs=2,
        type=seconds,
        metavar=("START", "DURATION"),
        help="arm-hand: the person carries the object out of the workspace at START s and back "
        "after DURATION s (instead of the perturbations)",
    )
    p.add_argument("--grasp", type=natural, default=0, help="stored power grasp index")
    p.add_argument("--theta", type=float, default=0.0, help="protocol pull [deg]; 0: loads only")
    p.add_argument("--seed", type=natural, default=0)
    p.add_argument("--latency", type=seconds, default=0.033, help="pose latency [s]")
    p.add_argument("--noise-mm", type=float, default=0.0)
    p.add_argument("--noise-deg", type=float, default=0.0)
    p.add_argument(
        "--dropout",
        nargs=2,
        action="append",
        metavar=("START", "DURATION"),
        help="no poses for DURATION s from START s of the protocol (repeatable)",
    )
    add_joint_gaps(p, "of the protocol or the episode")
    p.add_argument(
        "--pose-stamp",
        default="image",
        choices=["image", "processing"],
        help="stamp poses with the image time or the time processing ended",
    )
    p.add_argument(
        "--command-timeout",
        type=positive_seconds,
        default=0.1,
        help="the drives hold the last torque this long [s], then zero",
    )
    p.add_argument("--gravity", action="store_true")
    p.add_argument(
        "--wait", type=positive_seconds, default=60.0, help="wait this long for a controller [s]"
    )
    p.add_argument("--quick", action="store_true", help="shorter protocol phases")
    p.add_argument("--settle", type=positive_seconds, help="settle phase before the loads [s]")
    p.add_argument("--save", help="save the run record (.npz) for `wholehand view`")
    p.set_defaults(func=_cmd_hw_sim)
