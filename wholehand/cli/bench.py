"""``wholehand bench ...``: latency benchmarks that print JSON."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from wholehand.cli.arguments import add_joint_gaps, joint_gaps, rate


def _cmd_contacts(args: argparse.Namespace) -> int:
    from wholehand.bench.contacts import run_contact_benchmark

    params = {k: v for k, v in {"d_thresh": args.d_thresh, "k": args.k}.items() if v is not None}
    if args.recorded:
        from wholehand.bench.estimate import run_recorded_contact_benchmark

        recorded = run_recorded_contact_benchmark(
            hand=args.hand,
            obj=args.object,
            grasp=args.grasp,
            theta_deg=args.theta,
            estimator=args.estimator,
            estimator_params=params,
        )
        print(json.dumps(recorded, indent=2))
        return 0
    result = run_contact_benchmark(
        hand=args.hand,
        obj=args.object,
        estimator=args.estimator,
        cycles=args.cycles,
        seed=args.seed,
        d_thresh=args.d_thresh,
        k=args.k,
    )
    print(json.dumps(result, indent=2))
    return 0


def _cmd_allocate(args: argparse.Namespace) -> int:
    from wholehand.bench.allocate import run_allocation_benchmark

    kwargs = {"cycles": args.cycles, "seed": args.seed, "out_dir": Path(args.out)}
    if args.solvers:
        kwargs["solvers"] = tuple(args.solvers.split(","))
    result = run_allocation_benchmark(**kwargs)
    print(json.dumps(result, indent=2))
    return 0


def _cmd_cycle(args: argparse.Namespace) -> int:
    from wholehand.bench.cycle import run_cycle_benchmark

    options: dict[str, object] = {}
    if args.solver is not None:
        options["solver"] = args.solver
    if args.qp_deadline is not None:
        options["deadline"] = args.qp_deadline
    if args.qp_deadline_after_miss is not None:
        options["deadline_after_miss"] = args.qp_deadline_after_miss
    if args.screen_edges:
        options["screen_edges"] = True
    params: dict[str, object] = {"options": options} if options else {}
    if args.worst:
        from wholehand.bench.worst_case import WORST_OBJECTS, run_worst_case_benchmark

        worst = run_worst_case_benchmark(
            hand=args.hand,
            grasps=tuple(int(g) for g in args.grasps.split(",")),
            objects=WORST_OBJECTS if args.object is None else tuple(args.object.split(",")),
            estimator=args.estimator,
            allocator=args.allocator,
            allocator_params=params,
            estimator_params={} if args.hysteresis is None else {"hysteresis": args.hysteresis},
        )
        print(json.dumps(worst, indent=2))
        return 0

    from wholehand.models.object_catalogue import PAPER_OBJECTS

    objects = args.object or "077_rubiks_cube"
    result = run_cycle_benchmark(
        hand=args.hand,
        objects=PAPER_OBJECTS if objects == "paper" else tuple(objects.split(",")),
        ks=tuple(int(k) for k in args.k.split(",")),
        grasps=tuple(int(g) for g in args.grasps.split(",")),
        estimator=args.estimator,
        allocator=args.allocator,
        theta_deg=args.theta,
        allocator_params=params,
    )
    print(json.dumps(result, indent=2))
    return 0


def _cmd_soak(args: argparse.Namespace) -> int:
    from wholehand.bench.soak import run_soak

    result = run_soak(
        cycles=args.cycles, every=args.every, hand=args.hand, obj=args.object, grasp=args.grasp
    )
    print(json.dumps(result, indent=2))
    ok = result["exceptions"] == 0 and result["torque_limit_violations"] == 0
    return 0 if ok and result["recovered"] == result["n_injected"] else 1


def _cmd_reach(args: argparse.Namespace) -> int:
    from wholehand.reaching.episode import run_episode
    from wholehand.reaching.episode_spec import EpisodeSpec
    from wholehand.timing import percentiles

    cycle: dict[str, list[float]] = {}
    reacher: list[float] = []
    for seed in range(args.seed, args.seed + args.episodes):
        spec = EpisodeSpec(
            hand=args.hand, object=args.object, seed=seed, self_collision=args.self_collision
        )
        summary = run_episode(spec, samples=True)
        for kind, values in summary["cycle_samples_us"].items():
            cycle.setdefault(kind, []).extend(values)
        reacher.extend(summary["reacher_samples_us"])

    result = {
        "hand": args.hand,
        "object": args.object,
        "episodes": args.episodes,
        "self_collision": args.self_collision,
        "reacher_step_us": percentiles(reacher),
        "cycle_us": {kind: percentiles(v) for kind, v in cycle.items()},
    }
    print(json.dumps(result, indent=2))
    return 0


def _cmd_thin_walls(args: argparse.Namespace) -> int:
    from wholehand.bench.thin_walls import run_thin_wall_benchmark

    walls = tuple(float(w) for w in args.walls_mm.split(","))
    result = run_thin_wall_benchmark(walls_mm=walls, points=args.points, seed=args.seed)
    print(json.dumps(result, indent=2))
    return 0


def _cmd_hw(args: argparse.Namespace) -> int:
    from wholehand.bench.hw import run_hw_benchmark
    from wholehand.robot.controller import ControllerSpec

    spec = ControllerSpec(estimate_at=args.estimate_at, allocate_every=args.allocate_every)
    from wholehand.models.object_catalogue import PAPER_OBJECTS

    objects = PAPER_OBJECTS if args.object == "paper" else tuple(args.object.split(","))
    result = run_hw_benchmark(
        hand=args.hand,
        objects=objects,
        grasps=[int(g) for g in args.grasps.split(",")],
        latency=args.latency,
        quick=not args.full,
        spec=spec,
        pose_stamp=args.pose_stamp,
        stamp_source=args.stamp_source,
        sync_to_joint_states=not args.no_sync,
        config=args.config,
        transport=args.transport,
        flood=args.flood,
        flood_rate=args.flood_rate,
    )
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=2))
    return 0


def _cmd_pipeline(args: argparse.Namespace) -> int:
    from wholehand.bench.pipeline import run_pipeline_benchmark
    from wholehand.models.object_catalogue import PAPER_OBJECTS

    objects = PAPER_OBJECTS if args.object == "paper" else tuple(args.object.split(","))
    result = run_pipeline_benchmark(
        hand=args.hand,
        objects=objects,
        episodes=args.episodes,
        seed=args.seed,
        latency=args.latency,
        config=args.config,
        progress=lambda line: print(line, file=sys.stderr, flush=True),
        transport=args.transport,
        joint_gaps=joint_gaps(args),
        thread_priority=args.thread_priority,
    )
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(result, indent=1))
    print(json.dumps({k: v for k, v in result.items() if k != "rows"}, indent=2))
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    bench = sub.add_parser("bench", help="latency benchmarks (JSON with p50/p95/p99)")
    bsub = bench.add_subparsers(dest="bench", required=True)

    p = bsub.add_parser("contacts", help="contact-estimation latency at grasp-like states")
    p.add_argument("--hand", default="allegro_right")
    p.add_argument("--object", default="077_rubiks_cube")
    p.add_argument("--estimator", default="mesh_sdf")
    p.add_argument("--cycles", type=int, default=2000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--d-thresh", type=float, default=None, help="[m], default: paper's 0.01")
    p.add_argument("--k", type=int, default=None, help="contacts per link, default: paper's 5")
    p.add_argument(
        "--recorded",
        action="store_true",
        help="time kinematics, estimate and Jacobians on the states of a trial the loop ran "
        "(--grasp through the protocol at --theta) instead of seeded states",
    )
    p.add_argument("--grasp", type=int, default=0, help="with --recorded: stored grasp index")
    p.add_argument("--theta", type=float, default=60.0, help="with --recorded: pull [deg]")
    p.set_defaults(func=_cmd_contacts)

    p = bsub.add_parser("allocate", help="force-allocation QP solve time vs contact count")
    p.add_argument("--solvers", help="comma-separated qpsolvers names (default: every installed)")
    p.add_argument("--cycles", type=int, default=300)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="out/bench", help="folder for allocate.png")
    p.set_defaults(func=_cmd_allocate)

    p = bsub.add_parser("cycle", help="full control-step latency during held grasps, per K")
    p.add_argument("--hand", default="allegro_right")
    p.add_argument(
        "--object",
        help="comma-separated objects, or 'paper' for the paper's five (default: the cube; "
        "with --worst: the mustard bottle and the clamp)",
    )
    p.add_argument(
        "--theta",
        type=float,
        default=0.0,
        help="the protocol's pull [deg] (without --worst; default 0: the object held in place)",
    )
    p.add_argument("--k", default="1,3,5,7", help="comma-separated contacts per link")
    p.add_argument("--grasps", default="0,1", help="comma-separated grasp indices")
    p.add_argument(
        "--worst",
        action="store_true",
        help="replay the states of grasps lost at theta 90 deg: p50/p99/p99.9/max per stage",
    )
    p.add_argument(
        "--qp-deadline",
        type=float,
        help="the QP allocator's deadline [s] (default: none)",
    )
    p.add_argument(
        "--qp-deadline-after-miss",
        type=float,
        help="the QP allocator's deadline right after a missed one [s] (default: the same)",
    )
    p.add_argument(
        "--screen-edges",
        action="store_true",
        help="the QP allocator screens the pyramid-edge weights too",
    )
    p.add_argument(
        "--solver",
        default=None,
        help="the QP allocator's solver (default dual_active_set, the one built for this QP; "
        "daqp, osqp, piqp, ...)",
    )
    p.add_argument(
        "--hysteresis",
        type=float,
        default=None,
        metavar="M",
        help="--worst: the estimator's contact hysteresis in the replay [m] (0: the paper's "
        "selection; default 0.001); the trials keep the default, so settings compare on the "
        "same states",
    )
    p.add_argument("--estimator", default="mesh_sdf")
    p.add_argument("--allocator", default="qp")
    p.set_defaults(func=_cmd_cycle)

    p = bsub.add_parser(
        "soak",
        help="a held grasp for many cycles with a fault every N (exceptions, limit violations, "
        "recoveries, memory); exits 1 if any requirement fails",
    )
    p.add_argument("--cycles", type=int, default=100_000)
    p.add_argument("--every", type=int, default=100, help="one fault every this many cycles")
    p.add_argument("--hand", default="allegro_right")
    p.add_argument("--object", default="077_rubiks_cube")
    p.add_argument("--grasp", type=int, default=0)
    p.set_defaults(func=_cmd_soak)

    p = bsub.add_parser(
        "thin-walls",
        help="SDF sign and normal errors on tilted plates and shells, default spacing vs auto",
    )
    p.add_argument("--walls-mm", default="2,3,4,5", help="comma-separated wall thicknesses [mm]")
    p.add_argument("--points", type=int, default=4000, help="points per shape")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_cmd_thin_walls)

    p = bsub.add_parser(
        "reach",
        help="reacher QP and whole-cycle latency (reaching, regulation) over seeded episodes",
    )
    p.add_argument("--hand", default="allegro_right")
    p.add_argument("--object", default="077_rubiks_cube")
    p.add_argument("--episodes", type=int, default=3, help="seeded episodes")
    p.add_argument("--seed", type=int, default=0, help="seed of the first episode")
    p.add_argument(
        "--self-collision", action="store_true", help="the reacher keeps the fingers apart"
    )
    p.set_defaults(func=_cmd_reach)

    p = bsub.add_parser(
        "hw",
        help="hardware path on loopback: joint state -> torque message latency, rate held, "
        "and the load test through wholehand hw-sim",
    )
    p.add_argument("--hand", default="allegro_right")
    p.add_argument(
        "--object",
        default="077_rubiks_cube",
        help="comma-separated objects, or 'paper' for the paper's five",
    )
    p.add_argument("--grasps", default="0", help="comma-separated stored grasp indices")
    p.add_argument("--latency", type=float, default=0.033, help="pose latency [s]")
    p.add_argument("--full", action="store_true", help="the full load test (default: --quick)")
    p.add_argument("--estimate-at", default="object_stamp", choices=["object_stamp", "current"])
    p.add_argument("--allocate-every", default="cycle", choices=["cycle", "pose"])
    p.add_argument(
        "--pose-stamp",
        default="image",
        choices=["image", "processing"],
        help="what hw-sim's tracker stamps poses with",
    )
    p.add_argument(
        "--stamp-source",
        default="header",
        choices=["header", "receipt"],
        help="what the controller takes as a pose's time",
    )
    p.add_argument(
        "--no-sync",
        action="store_true",
        help="cycles do not wait for a fresh joint state ([rates] sync_to_joint_states = false)",
    )
    p.add_argument(
        "--config", help="hardware config TOML (default: ros2.toml in the hand's folder)"
    )
    p.add_argument(
        "--transport",
        default="zenoh",
        choices=["zenoh", "dds"],
        help="zenoh on a loopback TCP port, or DDS unicast on loopback",
    )
    p.add_argument(
        "--flood",
        choices=["bad", "valid"],
        default=None,
        help="a third node floods the joint-state topic meanwhile: bad (rejected) or valid "
        "(the robot's newest, re-stamped) joint states (wholehand/bench/flood_source.py)",
    )
    p.add_argument("--flood-rate", type=rate, default=10000.0, help="the flood's rate [Hz]")
    p.add_argument("--out", help="also write the JSON here")
    p.set_defaults(func=_cmd_hw)

    p = bsub.add_parser(
        "pipeline",
        help="the paper's Table I through the robot double (reach, grasp, hold, regrasp over "
        "ROS 2 messages) beside the same seeded episodes in process",
    )
    p.add_argument("--hand", default="flexiv_rizon4_hx5_d20_right", help="an arm-hand assembly")
    p.add_argument(
        "--object", default="077_rubiks_cube", help="comma-separated objects, or 'paper'"
    )
    p.add_argument("--episodes", type=int, default=3, help="seeded episodes per object")
    p.add_argument("--seed", type=int, default=0, help="seeds derived as `study reach` does")
    p.add_argument("--latency", type=float, default=0.033, help="the tracker's latency [s]")
    p.add_argument(
        "--config", help="hardware config TOML (default: ros2.toml in the hand's folder)"
    )
    p.add_argument(
        "--transport",
        default="zenoh",
        choices=["zenoh", "dds"],
        help="zenoh on a loopback TCP port, or DDS unicast on loopback",
    )
    add_joint_gaps(p, "of each episode")
    p.add_argument(
        "--thread-priority",
        type=int,
        help="the controller's SCHED_FIFO priority, 1-99, or 0 for none (default: the config's "
        "[rates] thread_priority; docs/hardware.md)",
    )
    p.add_argument("--out", help="also write the JSON (with every episode's row) here")
    p.set_defaults(func=_cmd_pipeline)
