"""The robot's streams hold deliveries back while a control cycle runs: a message that arrives
during a cycle is read once it ends, and every wait for messages ends the cycle first (no
deadlock). Threads are joined on events, never timed."""

from __future__ import annotations

import threading
import time

import numpy as np

from wholehand.ros2 import messages as msgs
from wholehand.ros2.config import HardwareConfig
from wholehand.ros2.inputs import JointStateReader
from wholehand.ros2.streams import RobotStreams
from wholehand.ros2.transport import SampleMeta

META = SampleMeta(0, bytes(16))


class Wires:
    """A transport whose subscriptions the test calls from threads of its own."""

    def __init__(self) -> None:
        self.callbacks: dict[str, object] = {}
        self.rejects: dict[str, object] = {}

    def subscriber(self, topic, msgtype, callback, rejected=None):
        self.callbacks[topic] = callback
        self.rejects[topic] = rejected

        class Subscription:
            def close(self) -> None:
                pass

        return Subscription()


class StoppedClock:
    """A clock that moves only when the test moves it [s]."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _streams(allegro, clock=time.monotonic) -> tuple[RobotStreams, Wires]:
    wires = Wires()
    config = HardwareConfig()
    return RobotStreams(config, JointStateReader(allegro, config), wires, clock), wires


def _state(allegro, stamp: float) -> bytes:
    return msgs.encode_joint_state(stamp, list(allegro.joint_names), allegro.neutral())


def _deliver(callback, *args) -> tuple[threading.Thread, threading.Event]:
    """``callback(*args)`` on a thread of its own; the event is set once it returned."""
    done = threading.Event()

    def run() -> None:
        callback(*args)
        done.set()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread, done


def test_a_message_arriving_during_a_cycle_is_read_when_the_cycle_ends(allegro) -> None:
    streams, wires = _streams(allegro)
    streams.start_cycle()
    payload = _state(allegro, time.time())
    joint, joint_done = _deliver(wires.callbacks["joint_states"], payload, META, 0.0)
    bad, bad_done = _deliver(wires.rejects["joint_states"], "no_attachment", "test")
    # Both threads block on the cycle: a gate that let them through would have them return.
    joint.join(0.2)
    bad.join(0.01)
    assert joint.is_alive() and bad.is_alive()
    assert not joint_done.is_set() and not bad_done.is_set()
    assert streams.received["joint_states"] == 0 and not streams.rejected
    streams.end_cycle()
    assert joint_done.wait(10.0) and bad_done.wait(10.0)
    assert streams.received["joint_states"] == 1
    assert streams.rejected == {"no_attachment": 1}
    latest = streams.latest().joint
    assert latest is not None
    np.testing.assert_allclose(latest.q, allegro.neutral())


def test_waiting_for_a_joint_state_ends_the_cycle_so_the_state_can_arrive(allegro) -> None:
    clock = StoppedClock()
    streams, wires = _streams(allegro, clock)
    wires.callbacks["joint_states"](_state(allegro, time.time() - 1.0), META, 0.0)
    clock.now += 100.0  # the state is 100 s old now; the next one arrives fresh
    streams.start_cycle()
    streams.start_cycle()  # a second start holds nothing more
    # The newest state is old: the wait must let the next one in, which a thread sends.
    _, done = _deliver(wires.callbacks["joint_states"], _state(allegro, time.time()), META, 0.0)
    how, _ = streams.wait_for_fresh_joint(fresh_age=50.0, max_wait=30.0)
    assert how in ("waited", "fresh") and done.wait(10.0)
    assert streams.received["joint_states"] == 2
    streams.start_cycle()
    streams.close()  # ends the cycle: a late delivery goes through, nothing deadlocks
    _, late = _deliver(wires.callbacks["joint_states"], _state(allegro, time.time()), META, 0.0)
    assert late.wait(10.0)
