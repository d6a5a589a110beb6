"""``wholehand bench pipeline``: the paper's Table I through the robot double, beside the same
episodes in process.

Each seeded episode runs twice: over ROS 2 messages, ``wholehand hw-sim`` playing the arm-hand
and the person in a second process while ``wholehand control``'s controller runs in this one
(in real time, the tracker at its rate with its latency); and in process, ``wholehand reach``'s
episode on the same seed (the same scene and person draws, no tracker latency). Per episode and
mode: acquisition, time to grasp, perturbations, losses, regrasps and the time they took,
returns home, completion, the controller's cycle times and overruns (over ROS 2 also the largest
torque rate the double's drives measured and its steps to zero); per mode, the counts with
the standard errors of the rates and of their paired differences.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
import tempfile
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from wholehand.bench.loopback import loopback
from wholehand.errors import ConfigError
from wholehand.models.hand import load_hand
from wholehand.models.object_catalogue import load_object
from wholehand.provenance import provenance
from wholehand.reaching.stages import HOME, PREGRASP, REGULATE
from wholehand.robot.controller import ControllerSpec, run_controller
from wholehand.robot.realtime import check_priority
from wholehand.ros2.config_file import hand_hardware_config, load_hardware_config
from wholehand.studies.base import derive_seed
from wholehand.timing import percentiles

RIG = "flexiv_rizon4_hx5_d20_right"


def _outcome(
    transitions: list[dict[str, Any]], t0: float, complete: bool, perturbations: int
) -> dict[str, Any]:
    """An episode's Table I columns from its stage transitions (times from ``t0`` [s])."""
    grasps = [t["t"] - t0 for t in transitions if t["target"] == REGULATE]
    losses = [
        t["t"] - t0 for t in transitions if t["source"] == REGULATE and t["target"] == PREGRASP
    ]
    regrasp_times = []
    for lost in losses:
        after = [g for g in grasps if g > lost]
        if after:
            regrasp_times.append(after[0] - lost)
    return {
        "acquired": bool(grasps),
        "time_to_grasp_s": grasps[0] if grasps else None,
        "perturbations": perturbations,
        "losses": len(losses),
        "loss_times_s": losses,
        "regrasps": len(regrasp_times),
        "time_to_regrasp_s": regrasp_times,
        "returns_home": sum(t["target"] == HOME for t in transitions),
        "complete": complete,
    }


def over_ros(
    hand: str,
    obj: str,
    seed: int,
    config: Path,
    latency: float,
    duration: float,
    transport: str = "zenoh",
    joint_gaps: Sequence[tuple[float, float]] = (),
    thread_priority: int | None = None,
) -> dict[str, Any]:
    """One episode through the double (a second process) and the controller (this one), over
    ``transport`` (:func:`~wholehand.bench.loopback.loopback`); the double publishes no joint
    state during each of ``joint_gaps`` (``(start, duration)`` [s] of the episode). The
    controller runs at ``thread_priority`` (None: the config's)."""
    hw_config, link = loopback(load_hardware_config(config), transport)
    if thread_priority is not None:
        hw_config = dataclasses.replace(hw_config, thread_priority=thread_priority)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "sim.json"
        argv = [sys.executable, "-m", "wholehand.cli.main", "hw-sim", "--config", str(config),
                "--hand", hand, "--object", obj, "--seed", str(seed), "--latency", str(latency),
                "--duration", str(duration), *link, "--json", str(out)]  # fmt: skip
        for start, length in joint_gaps:
            argv += ["--joint-gap", str(start), str(length)]
        sim = subprocess.Popen(
            argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
            env=os.environ.copy(),
        )  # fmt: skip
        try:
            result = run_controller(
                load_hand(hand), load_object(obj), hw_config, ControllerSpec(), trace=True,
                stop=sim.poll,
            )  # fmt: skip
            _, err = sim.communicate(timeout=120)
        finally:
            if sim.poll() is None:
                sim.kill()
        if not out.exists():
            raise ConfigError(f"bench pipeline: hw-sim failed on {obj} seed {seed}: {err[-2000:]}")
        robot = json.loads(out.read_text())
    loop = result["loop"]
    row = _outcome(
        loop["transitions"], robot["start_monotonic_s"], robot["complete"], robot["perturbations"]
    )
    cycle_ms = [1e3 * t for t in result["cycle_times_s"]]
    return {
        **row,
        "cycle_ms": percentiles(cycle_ms),
        "overruns": loop["overruns"],
        "late_cycles": result["late_cycles"],
        "reacher_faults": result["reacher_faults"],
        "late_cycles_double": robot["late_cycles"],
        "joint_states_withheld": robot["joint_states_withheld"],
        "max_torque_rate_Nm_s": robot["max_torque_rate_Nm_s"],
        "stops_to_zero": robot["stops_to_zero"],
        "rejected": result["backend"]["rejected"],
        "guard": result["backend"]["guard"],
        "joint_gaps": result["backend"]["joint_gaps"],
        "arm_guard": result["backend"]["arm_guard"],
        "events": robot["events"],
    }


def in_process(hand: str, obj: str, seed: int) -> dict[str, Any]:
    """The same episode in process (``wholehand reach``)."""
    from wholehand.reaching.episode import run_episode
    from wholehand.reaching.episode_spec import EpisodeSpec

    summary = run_episode(EpisodeSpec(hand=hand, object=obj, seed=seed), samples=True)
    row = _outcome(
        summary["transitions"], 0.0, bool(summary["complete"]), int(summary["perturbations"])
    )
    cycles = [t for times in summary["cycle_samples_us"].values() for t in times]
    return {
        **row,
        "cycle_ms": percentiles([1e-3 * t for t in cycles]),
        "overruns": 0,
        "reacher_faults": summary["reacher_faults"],
        "events": summary["events"],
    }


def _rate(rows: list[dict[str, Any]], key: str) -> dict[str, float]:
    x = np.array([bool(r[key]) for r in rows], dtype=float)
    n = max(len(x), 1)
    return {"rate": float(x.mean()), "se": float(math.sqrt(x.mean() * (1 - x.mean()) / n))}


def _paired(a: list[dict[str, Any]], b: list[dict[str, Any]], key: str) -> dict[str, float]:
    """Mean and standard error of the paired difference a - b of a yes/no column."""
    d = np.array([float(bool(x[key])) - float(bool(y[key])) for x, y in zip(a, b, strict=True)])
    se = float(d.std(ddof=1) / math.sqrt(len(d))) if len(d) > 1 else float("nan")
    return {"difference": float(d.mean()), "se": se}


def _late_summary(late: list[dict[str, Any]]) -> dict[str, Any]:
    """The late cycles of all episodes by stage and status, and where their time went: the
    cycle alone took more than its period; the joint-state wait before it and the cycle did;
    neither did (the observers, the sleep's overshoot, the operating system). Also how many
    saw a garbage collection."""
    alone = [c["cycle_s"] > c["period_s"] for c in late]
    with_wait = [c["cycle_s"] + c["joint_wait_s"] > c["period_s"] for c in late]
    return {
        "kept": len(late),
        "by_stage": dict(Counter(f"{c['stage']}/{c['status']}" for c in late).most_common()),
        "cycle_over_period": sum(alone),
        "wait_and_cycle_over_period": sum(
            w and not a for a, w in zip(alone, with_wait, strict=True)
        ),
        "elsewhere": sum(not w for w in with_wait),
        "with_collection": sum(c["collections"] > 0 for c in late),
        "cycle_s_max": max((c["cycle_s"] for c in late), default=None),
    }


def _totals(rows: list[dict[str, Any]]) -> dict[str, Any]:
    regrasp = [t for r in rows for t in r["time_to_regrasp_s"]]
    grasp = [r["time_to_grasp_s"] for r in rows if r["time_to_grasp_s"] is not None]
    cycles_p50 = [r["cycle_ms"]["p50"] for r in rows if r["cycle_ms"]["p50"] is not None]
    cycles_p99 = [r["cycle_ms"]["p99"] for r in rows if r["cycle_ms"]["p99"] is not None]
    rates = [r["max_torque_rate_Nm_s"] for r in rows if "max_torque_rate_Nm_s" in r]
    gaps = [r["joint_gaps"] for r in rows if "joint_gaps" in r]
    return {
        "episodes": len(rows),
        "acquired": sum(r["acquired"] for r in rows),
        "acquired_rate": _rate(rows, "acquired"),
        "time_to_grasp_s_median": float(np.median(grasp)) if grasp else None,
        "perturbations": sum(r["perturbations"] for r in rows),
        "losses": sum(r["losses"] for r in rows),
        "regrasps": sum(r["regrasps"] for r in rows),
        "time_to_regrasp_s_median": float(np.median(regrasp)) if regrasp else None,
        "returns_home": sum(r["returns_home"] for r in rows),
        "completed": sum(r["complete"] for r in rows),
        "completed_rate": _rate(rows, "complete"),
        "cycle_ms_p50_median": float(np.median(cycles_p50)) if cycles_p50 else None,
        "cycle_ms_p99_max": float(max(cycles_p99)) if cycles_p99 else None,
        "overruns": sum(r["overruns"] for r in rows),
        "late_cycles": _late_summary([c for r in rows for c in r.get("late_cycles", ())]),
        "reacher_faults": dict(
            sum((Counter(r.get("reacher_faults", {})) for r in rows), Counter())
        ),
        "max_torque_rate_Nm_s": max(rates) if rates else None,
        # Joint-state gaps that ended mid-episode (those open at the end: the double stopped).
        "joint_gaps_mid_episode": sum(g["recovered"] for g in gaps) if gaps else None,
        "joint_gaps_mid_episode_past_hold": (
            sum(g["recovered_past_hold"] for g in gaps) if gaps else None
        ),
        "joint_gap_longest_mid_episode_s": (
            max(g["longest_recovered_s"] for g in gaps) if gaps else None
        ),
    }


def run_pipeline_benchmark(
    hand: str = RIG,
    objects: Sequence[str] = ("077_rubiks_cube",),
    episodes: int = 3,
    seed: int = 0,
    latency: float = 0.033,
    duration: float = 14.0,
    config: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
    transport: str = "zenoh",
    joint_gaps: Sequence[tuple[float, float]] = (),
    thread_priority: int | None = None,
) -> dict[str, Any]:
    """Run ``episodes`` seeded episodes per object over ROS (``transport``: zenoh or dds; no
    joint states from the double during ``joint_gaps``, ``(start, duration)`` [s] of each
    episode; the controller at ``thread_priority``, None: the config's) and in process (seeds
    as ``wholehand study reach`` derives them); JSON-ready rows and totals per mode, with the
    paired differences of acquisition and completion."""
    if episodes < 1:
        raise ConfigError(f"bench pipeline: episodes must be >= 1, got {episodes}")
    config_path = hand_hardware_config(hand) if config is None else Path(config)
    hw_config = load_hardware_config(config_path)
    priority = hw_config.thread_priority
    if thread_priority is not None:
        check_priority(thread_priority)  # a refusal is a ConfigError before any episode
        priority = thread_priority
    made_by = provenance()  # the code the episodes run, not a commit made meanwhile
    ros, local, rows = [], [], []
    for oi, obj in enumerate(objects):
        for episode in range(episodes):
            episode_seed = derive_seed(seed, oi, episode)
            a = over_ros(
                hand, obj, episode_seed, config_path, latency, duration, transport, joint_gaps,
                priority,
            )  # fmt: skip
            b = in_process(hand, obj, episode_seed)
            ros.append(a)
            local.append(b)
            rows.append({"object": obj, "seed": episode_seed, "ros2": a, "in_process": b})
            if progress is not None:
                progress(
                    f"{obj} seed {episode_seed}: over ROS 2 acquired={a['acquired']} "
                    f"losses={a['losses']} regrasps={a['regrasps']} complete={a['complete']}; "
                    f"in process acquired={b['acquired']} losses={b['losses']} "
                    f"regrasps={b['regrasps']} complete={b['complete']}"
                )
    return {
        "provenance": made_by,
        "hand": hand,
        "objects": list(objects),
        "episodes_per_object": episodes,
        "transport": transport,
        "joint_gaps_s": [list(gap) for gap in joint_gaps],
        "thread_priority": priority,
        "tracker": {
            "rate_hz": hw_config.object_pose_rate,
            "latency_s": latency,
        },  # fmt: skip
        "ros2": _totals(ros),
        "in_process": _totals(local),
        "paired_ros2_minus_in_process": {
            "acquired": _paired(ros, local, "acquired"),
            "completed": _paired(ros, local, "complete"),
        },
        "rows": rows,
    }
