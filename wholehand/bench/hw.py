"""``wholehand bench hw``: the hardware path end to end on loopback, against ``wholehand hw-sim``.

For each grasp, the double runs in its own process (MuJoCo in real time, joint states at the
config's rate, poses at 30 Hz with a latency) and the controller runs in this one. Every torque
message is matched, by its attachment's sequence number, with the joint state it answered:

- ``answer_ms``: from the joint state's stamp (its measurement time) to the torque message's
  arrival at the robot: the sample's age when the cycle began, the cycle, and the transport;
- ``controller_ms``: from that stamp to the message's publication (``answer_ms`` less transport);
- ``transport_ms``: publication to arrival;
- ``cycle_ms``: the controller's cycles themselves (reading the newest messages, the stage, the
  torque guard and the publication; the waits between cycles left out): the control step on
  a machine where the simulator is another process, as on a robot;
- ``rate_hz``: torque messages the robot received per second of its run, on its wall clock
  (the rate held).

All times are wall-clock on one machine (one clock for both processes). ``plain_loop_held``
counts the same grasps held in the simulation loop with the tracker modelled by its filters.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from wholehand.bench.loopback import loopback
from wholehand.errors import ConfigError
from wholehand.models.hand import load_hand
from wholehand.models.object_catalogue import load_object
from wholehand.robot.controller import ControllerSpec, run_controller
from wholehand.ros2.config import HardwareConfig, StampSource
from wholehand.ros2.config_file import hand_hardware_config, load_hardware_config
from wholehand.ros2.rmw_zenoh import loopback_endpoint
from wholehand.timing import percentiles

POINTS = (50, 95, 99)
"""Percentiles reported [%]."""


def run_hw_benchmark(
    hand: str = "allegro_right",
    objects: Sequence[str] = ("077_rubiks_cube",),
    grasps: Sequence[int] = (0,),
    latency: float = 0.033,
    quick: bool = True,
    spec: ControllerSpec | None = None,
    pose_stamp: str = "image",
    stamp_source: StampSource = "header",
    sync_to_joint_states: bool = True,
    config: str | Path | None = None,
    transport: str = "zenoh",
    flood: str | None = None,
    flood_rate: float = 10000.0,
) -> dict[str, Any]:
    """Run the double and the controller over each grasp of each object; latency percentiles
    over all messages, and whether each grasp held the load test. ``sync_to_joint_states``:
    the controller's setting of that name (:mod:`wholehand.ros2.config_file`); ``config``: the
    hardware config both use (None: the hand folder's ``ros2.toml``); ``transport``: zenoh
    (a free TCP port on loopback) or dds (unicast on loopback, the domain of the config or
    ``$ROS_DOMAIN_ID``); ``flood``: ``bad`` or ``valid`` joint states sent at ``flood_rate``
    [Hz] by a third node meanwhile (:mod:`wholehand.bench.flood_source`), None for none."""
    spec = spec or ControllerSpec()
    config_path = hand_hardware_config(hand) if config is None else Path(config)
    hand_model = load_hand(hand)
    answer, controller, wire, rates, rows = [], [], [], [], []
    flood_sent: list[float] = []
    cycles: list[float] = []
    for obj, grasp in ((o, g) for o in objects for g in grasps):
        obj_model = load_object(obj)
        # A flooding node reaches the controller directly: zenoh peers do not route for others.
        flood_endpoint = loopback_endpoint() if flood is not None else None
        base = replace(
            load_hardware_config(config_path),
            stamp_source=stamp_source,
            sync_to_joint_states=sync_to_joint_states,
        )
        listen = () if flood_endpoint is None else (flood_endpoint,)
        hw_config, link = loopback(base, transport, listen)
        endpoint = hw_config.connect[0] if transport == "zenoh" else ""
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "sim.json"
            argv = [
                sys.executable,
                "-m",
                "wholehand.cli.main",
                "hw-sim",
                "--config",
                str(config_path),
                "--hand",
                hand,
                "--object",
                obj,
                "--grasp",
                str(grasp),
                "--latency",
                str(latency),
                "--pose-stamp",
                pose_stamp,
                *link,
                "--json",
                str(out),
                *(["--quick"] if quick else []),
            ]
            sim = subprocess.Popen(
                argv,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                text=True,
                env=os.environ.copy(),
            )
            flooder = None
            if flood is not None:
                flooder = _start_flood(
                    Path(tmp) / "flood.json",
                    config_path,
                    hand,
                    flood,
                    flood_rate,
                    transport,
                    (endpoint, flood_endpoint or endpoint),
                )
            try:
                result = run_controller(
                    hand_model, obj_model, hw_config, spec, trace=True, duration=None, stop=sim.poll
                )
                _, err = sim.communicate(timeout=60)
            finally:
                if sim.poll() is None:
                    sim.kill()
                if flooder is not None:
                    _stop(flooder)
            sent = Path(tmp) / "flood.json"
            if flooder is not None and sent.exists():
                flood_sent.append(json.loads(sent.read_text())["sent_hz"])
            if not out.exists():
                raise ConfigError(f"bench hw: hw-sim failed for {obj} grasp {grasp}: {err[-2000:]}")
            robot = json.loads(out.read_text())
        cycles.extend(1e3 * t for t in result["cycle_times_s"])
        arrivals = dict(robot["arrivals"])
        for _, stamp_q, published_ns in result["trace"]:
            if published_ns in arrivals and np.isfinite(stamp_q):
                arrived = arrivals[published_ns]
                answer.append(1e3 * (1e-9 * arrived - stamp_q))
                controller.append(1e3 * (1e-9 * published_ns - stamp_q))
                wire.append(1e-6 * (arrived - published_ns))
        start, end = robot["run_wall_ns"]
        during = sum(start <= t <= end for t in arrivals.values())
        rates.append(during / (1e-9 * (end - start)))
        rows.append(
            {
                "object": obj,
                "grasp": grasp,
                "held": robot["held"],
                "lost_at": robot["lost_at"],
                "statuses": robot["statuses"],
                "rejected": result["backend"]["rejected"],
                "arrived": result["backend"]["arrived"],
                "superseded": result["backend"]["superseded"],
                "guard": result["backend"]["guard"],
                "joint_gaps": result["backend"]["joint_gaps"],
                "sync": result["backend"]["sync"],
                "sync_wait_s": result["backend"]["sync_wait_s"],
                "late_cycles": robot["late_cycles"],
                "max_torque_rate_Nm_s": robot["max_torque_rate_Nm_s"],
            }
        )
    for row in rows:
        row["plain_loop_held"] = _plain_loop(
            hand, row["object"], row["grasp"], latency, quick, spec
        )
    plain = [row["plain_loop_held"] for row in rows]
    return {
        "plain_loop_held": sum(plain),
        "hand": hand,
        "objects": list(objects),
        "transport": transport,
        "latency_s": latency,
        "quick": quick,
        "estimate_at": spec.estimate_at,
        "allocate_every": spec.allocate_every,
        "pose_stamp": pose_stamp,
        "stamp_source": stamp_source,
        "sync_to_joint_states": sync_to_joint_states,
        "held": sum(r["held"] for r in rows),
        "grasps": len(rows),
        "answer_ms": percentiles(answer, POINTS),
        "controller_ms": percentiles(controller, POINTS),
        "transport_ms": percentiles(wire, POINTS),
        "cycle_ms": percentiles(cycles, POINTS),
        "messages": len(answer),
        "rate_hz": {"min": float(min(rates)), "mean": float(np.mean(rates))},
        "control_rate_hz": load_hardware_config(config_path).control_rate,
        "flood": None
        if flood is None
        else {
            "kind": flood,
            "rate_hz": flood_rate,
            "sent_hz": float(np.mean(flood_sent)) if flood_sent else None,
        },
        "runs": rows,
    }


def _stop(process: subprocess.Popen[str], grace: float = 10.0) -> None:
    """SIGTERM, then SIGKILL past ``grace`` [s] (a transport call that blocks in C keeps the
    signal from being handled)."""
    process.terminate()
    try:
        process.wait(timeout=grace)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(timeout=grace)


def _start_flood(
    out: Path,
    config: Path,
    hand: str,
    kind: str,
    rate: float,
    transport: str,
    endpoints: tuple[str, str],
) -> subprocess.Popen[str]:
    """The flooding node (:mod:`wholehand.bench.flood_source`) in its own process."""
    argv = [
        sys.executable,
        "-m",
        "wholehand.bench.flood_source",
        "--config",
        str(config),
        "--hand",
        hand,
        "--kind",
        kind,
        "--rate",
        str(rate),
        "--transport",
        transport,
        "--connect",
        ",".join(endpoints),
        "--json",
        str(out),
    ]
    return subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, text=True)


def _plain_loop(
    hand: str, obj: str, grasp: int, latency: float, quick: bool, spec: ControllerSpec
) -> bool:
    """The same grasp and load test in the simulation loop, with the tracker modelled by the
    loop's filters (30 Hz, the same latency): does it hold?"""
    from wholehand.trials.trial import TrialSpec, run_trial

    params = {"settle_time": 0.3, "load_duration": 0.3} if quick else {}
    trial = TrialSpec(
        hand=hand,
        object=obj,
        grasp=grasp,
        theta_deg=0.0,
        estimate_at=spec.estimate_at,
        estimator=spec.estimator,
        allocator=spec.allocator,
        protocol_params=params,
        tracking={"rate_hz": HardwareConfig().object_pose_rate, "latency_s": latency},
    )
    return bool(run_trial(trial, stop_on_loss=True).held_throughout)
