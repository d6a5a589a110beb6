"""The robot's streams under a flood of joint states: decodes on the transport's threads limited
by a token bucket, the newest kept for the controller, every delivered message counted once,
and the controller's history thinned; on a clock the test sets, not on timing."""

from __future__ import annotations

import time

import numpy as np
import pytest

from wholehand.ros2 import messages as msgs
from wholehand.ros2.config import HardwareConfig
from wholehand.ros2.inputs import JointStateReader
from wholehand.ros2.streams import (
    DECODE_BURST,
    DECODE_SPACING,
    HISTORY_SPACING,
    RobotStreams,
)
from wholehand.ros2.transport import SampleMeta


class StoppedClock:
    """A clock that moves only when the test moves it [s]."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class Wires:
    """A transport whose subscriptions the test calls by hand."""

    def __init__(self) -> None:
        self.callbacks: dict[str, object] = {}

    def subscriber(self, topic, msgtype, callback, rejected=None):
        self.callbacks[topic] = callback

        class Subscription:
            def close(self) -> None:
                pass

        return Subscription()


META = SampleMeta(0, bytes(16))


@pytest.fixture
def streams(allegro):
    clock = StoppedClock()
    wires = Wires()
    config = HardwareConfig()
    out = RobotStreams(config, JointStateReader(allegro, config), wires, clock)
    return out, wires.callbacks["joint_states"], clock


def _state(allegro, stamp: float, q0: float = 0.0, nan: bool = False) -> bytes:
    q = allegro.neutral() + q0
    if nan:
        q[0] = np.nan
    return msgs.encode_joint_state(stamp, list(allegro.joint_names), q)


def test_a_flood_is_decoded_up_to_a_burst_and_the_newest_reaches_the_controller(allegro, streams):
    s, deliver, clock = streams
    t0 = time.time() - 1.0
    for i in range(50):  # 50 states at one instant: a burst is decoded, the rest kept
        deliver(_state(allegro, t0 + 1e-5 * i, q0=0.001 * i), META, 0.0)
    burst = int(DECODE_BURST)
    assert s.received["joint_states"] == burst and s.superseded == 50 - burst - 1
    assert s.arrived["joint_states"] == 50
    latest = s.latest()  # the controller decodes the one kept
    assert latest.joint is not None and latest.joint.stamp == pytest.approx(t0 + 49e-5)
    np.testing.assert_allclose(latest.joint.q, allegro.neutral() + 0.049)
    assert s.received["joint_states"] + s.superseded == s.arrived["joint_states"]
    # A spacing later one more is decoded on arrival.
    clock.now += 1.2 * DECODE_SPACING
    deliver(_state(allegro, t0 + 0.1), META, 0.0)
    assert s.received["joint_states"] == burst + 2 and s.superseded == 50 - burst - 1


def test_bad_states_in_a_flood_are_counted_where_decoded_and_superseded_otherwise(allegro, streams):
    """After a burst, arrivals 0.55 spacings apart: 21 of them bring 11.55 decodes' worth, so
    11 are decoded (rejected) on arrival, 9 superseded and the last kept for the controller."""
    s, deliver, clock = streams
    t0 = time.time() - 1.0
    for i in range(int(DECODE_BURST)):
        deliver(_state(allegro, t0 + 1e-4 * i), META, 0.0)
    good = s.latest().joint
    for i in range(1, 22):
        clock.now += 0.55 * DECODE_SPACING
        deliver(_state(allegro, t0 + 1e-3 * i, nan=True), META, 0.0)
    assert s.rejected["not_finite"] == 11 and s.superseded == 9
    assert s.latest().joint is good  # the last good state stays
    assert s.rejected["not_finite"] == 12  # the one kept, checked by the controller
    assert s.arrived["joint_states"] == 8 + 21 == 8 + 12 + s.superseded  # each counted once


def test_the_history_gets_joint_states_at_least_a_spacing_apart(allegro, streams):
    s, deliver, clock = streams
    t0 = time.time() - 1.0
    for i in range(40):  # 4 kHz of states by their stamps, each decoded on arrival
        clock.now += 2 * DECODE_SPACING
        deliver(_state(allegro, t0 + 2.5e-4 * i), META, 0.0)
    stamps = np.array([sample.stamp for sample in s.take_pending()])
    assert s.received["joint_states"] == 40
    assert stamps.size == 10 and (np.diff(stamps) > HISTORY_SPACING - 1e-6).all()  # ns stamps
    assert s.take_pending() == []


def test_the_flood_restamps_a_joint_state_in_its_bytes(allegro):
    """The flooding node writes the stamp into the CDR bytes; decoding them gives that stamp
    and the same joint state, as encoding it with that stamp does."""
    from wholehand.bench.flood_source import restamped

    q = allegro.neutral() + 0.01
    payload = msgs.encode_joint_state(12.5, list(allegro.joint_names), q)
    again = restamped(payload, 1765000000.123456789)
    decoded = msgs.decode_joint_state(again)
    assert decoded.stamp == pytest.approx(1765000000.123456789, abs=1e-6)
    np.testing.assert_array_equal(decoded.position, q)
    assert decoded.names == tuple(allegro.joint_names)
    assert again == msgs.encode_joint_state(decoded.stamp, list(allegro.joint_names), q)


def test_the_wait_for_a_fresh_joint_state_decodes_the_one_kept_first(allegro, streams):
    s, deliver, clock = streams
    t0 = time.time() - 1.0
    for i in range(int(DECODE_BURST) + 1):  # the burst, and one kept undecoded
        deliver(_state(allegro, t0 + 1e-4 * i), META, 0.0)
    assert s.received["joint_states"] == DECODE_BURST
    assert s.wait_for_fresh_joint(fresh_age=1.0, max_wait=0.0)[0] == "fresh"
    assert s.received["joint_states"] == DECODE_BURST + 1  # decoded before the check
