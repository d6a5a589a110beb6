"""A third node that floods the controller's joint-state topic (``wholehand bench hw --flood``).

Run as its own process (``python -m wholehand.bench.flood_source``) beside the robot double and
the controller, it publishes on the config's ``joint_states`` topic at a fixed rate until it is
stopped (SIGTERM), then writes what it sent as JSON:

- ``bad``: joint states the controller must reject after decoding them, alternately with a NaN
  position (``not_finite``) and with a joint the hand does not have (``unknown_joint``); over
  zenoh every third one is not CDR at all (``malformed``; DDS delivers only samples of the
  topic's type);
- ``valid``: the robot's own newest joint state (from the first publisher heard on the topic,
  the double), re-stamped with the time of sending: good messages at a rate far above the
  robot's, as from a misconfigured driver.

Stamps are written into the CDR bytes directly (header.stamp.sec and nanosec follow the 4-byte
encapsulation header), so sending costs no encoding.
"""

from __future__ import annotations

import argparse
import json
import signal
import struct
import threading
import time
from dataclasses import replace
from pathlib import Path
from types import FrameType

import numpy as np

from wholehand.models.hand import load_hand
from wholehand.ros2 import messages as msgs
from wholehand.ros2.config import HardwareConfig, QoS
from wholehand.ros2.config_file import load_hardware_config
from wholehand.ros2.node import open_transport
from wholehand.ros2.transport import SampleMeta

KINDS = ("bad", "valid")
"""What the flood sends (module docstring)."""
STAMP_OFFSET = 4
"""Byte offset of ``header.stamp.sec`` in a JointState's CDR payload."""
BATCH = 10
"""Messages sent between two looks at the clock."""


def restamped(payload: bytes, t: float) -> bytes:
    """``payload`` (a CDR JointState, little-endian) with its header stamped ``t`` [s]."""
    out = bytearray(payload)
    sec = int(t)
    struct.pack_into("<iI", out, STAMP_OFFSET, sec, int(round((t - sec) * 1e9)) % 1_000_000_000)
    return bytes(out)


class Newest:
    """The newest joint-state payload of the first publisher heard on the topic."""

    def __init__(self) -> None:
        self.source: bytes | None = None
        self.payload: bytes | None = None
        self.lock = threading.Lock()

    def __call__(self, payload: bytes, meta: SampleMeta, _: float) -> None:
        with self.lock:
            if self.source is None:
                self.source = meta.source
            if meta.source == self.source:
                self.payload = payload


def _bad_payloads(hand_name: str, zenoh: bool) -> list[tuple[bytes, bool]]:
    """The bad messages sent in turn, each with whether it is CDR (then re-stamped)."""
    hand = load_hand(hand_name)
    names = list(hand.joint_names)
    q = hand.neutral()
    nan = q.copy()
    nan[0] = np.nan
    out = [
        (msgs.encode_joint_state(0.0, names, nan), True),
        (msgs.encode_joint_state(0.0, ["wrist", *names[1:]], q), True),
    ]
    if zenoh:
        out.append((b"\x00\x01\x00\x00" + bytes(range(256)) * 2, False))
    return out


def flood(config: HardwareConfig, hand: str, kind: str, rate: float, out: Path) -> None:
    """Publish ``kind`` joint states at ``rate`` [Hz] until SIGTERM or SIGINT, then write the
    count sent and the rate achieved to ``out`` (JSON)."""
    stop = threading.Event()

    def handle(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, handle)
    signal.signal(signal.SIGINT, handle)
    transport = open_transport(config, "wholehand_flood")
    # The robot's states come in on a node of their own, best effort: a reliable reader in the
    # writing process held Cyclone's writer up (its acknowledgements need the interpreter).
    reader = None
    if kind == "valid":
        best_effort = QoS(reliability="best_effort")
        reader = open_transport(
            replace(config, qos={**config.qos, "joint_states": best_effort}), "wholehand_flood_in"
        )
    sent = 0
    started = time.monotonic()
    try:
        publisher = transport.publisher("joint_states", msgs.JOINT_STATE)
        newest = Newest()
        if reader is not None:
            reader.subscriber("joint_states", msgs.JOINT_STATE, newest)
        bad = _bad_payloads(hand, config.transport == "zenoh")
        period = 1.0 / rate
        started = time.monotonic()
        while not stop.is_set():
            due = started + sent * period
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            for _ in range(BATCH):
                if kind == "valid":
                    with newest.lock:
                        payload = newest.payload
                    if payload is None:
                        break
                    publisher.put(restamped(payload, time.time()))
                else:
                    template, is_cdr = bad[sent % len(bad)]
                    publisher.put(restamped(template, time.time()) if is_cdr else template)
                sent += 1
            else:
                continue
            time.sleep(0.01)  # no joint state from the robot yet
    finally:
        elapsed = time.monotonic() - started
        transport.close()
        if reader is not None:
            reader.close()
        out.write_text(json.dumps({"kind": kind, "sent": sent, "sent_hz": sent / elapsed}))


def flood_config(config: HardwareConfig, transport: str, endpoints: str) -> HardwareConfig:
    """``config`` set to reach the double and the controller on loopback as ``wholehand bench
    hw`` runs them: zenoh connected to the comma-separated ``endpoints`` (both nodes'), or DDS
    unicast on loopback (the domain of ``$ROS_DOMAIN_ID`` unless the config names one)."""
    if transport == "dds":
        return replace(config, transport="dds", dds_interface="127.0.0.1", dds_peers=("127.0.0.1",))
    return replace(config, transport="zenoh", connect=tuple(endpoints.split(",")), listen=())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--config", required=True, help="the hardware config (TOML)")
    p.add_argument("--hand", default="allegro_right")
    p.add_argument("--kind", choices=KINDS, required=True)
    p.add_argument("--rate", type=float, default=10000.0, help="messages per second")
    p.add_argument("--transport", choices=("zenoh", "dds"), default="zenoh")
    p.add_argument("--connect", default="", help="zenoh: comma-separated endpoints")
    p.add_argument("--json", required=True, help="write what was sent here")
    args = p.parse_args(argv)
    config = flood_config(load_hardware_config(args.config), args.transport, args.connect)
    flood(config, args.hand, args.kind, args.rate, Path(args.json))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
