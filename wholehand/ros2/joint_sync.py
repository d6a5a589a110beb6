"""Whether a cycle waits for a fresh joint state, and for how long (``[rates]
sync_to_joint_states``; :mod:`wholehand.ros2.config_file` says why).

A cycle whose newest joint state arrived more than a quarter of a joint-state period ago waits
for the next one, at most 1.25 joint-state periods and 40 % of the control period, and never
so long that the cycle's own computation would then run past its period: the wait leaves the
highest computation time of the recent cycles, plus :data:`MARGIN`, free. A stage that
computes longer (the reacher's inverse kinematics, a replan) thus starts on the newest state as
it finds it instead of coming late.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from typing import Protocol

from wholehand.ros2.config import HardwareConfig

MARGIN = 0.0005
"""Time a wait leaves free beyond the recent cycles' highest computation time [s]."""
DECAY = 0.995
"""Per cycle, the factor by which the recent highest computation time forgets a slow cycle
(halved in about 140 cycles: 0.7 s at 200 Hz)."""


class FreshJointSource(Protocol):
    def wait_for_fresh_joint(self, fresh_age: float, max_wait: float) -> tuple[str, float]: ...


class JointSync:
    """The wait before each cycle, and the cycles' computation times it allows for.

    Args:
        config: The hardware config (its rates and ``sync_to_joint_states``).
        clock: The backend's monotonic clock [s].

    Attributes:
        counts: cycles by how they met the joint states: ``fresh`` (the newest was fresh),
            ``waited`` (the next arrived within the wait), ``timed_out`` (it did not),
            ``no_time`` (the recent cycles' computation left no time to wait).
        waited: time spent waiting, in all [s].
        compute_high: the highest computation time of the recent cycles [s] (:data:`DECAY`).
    """

    def __init__(self, config: HardwareConfig, clock: Callable[[], float]) -> None:
        joint_period = 1.0 / config.joint_state_rate
        self.fresh_age = 0.25 * joint_period
        self.max_wait = (
            min(1.25 * joint_period, 0.4 / config.control_rate)
            if config.sync_to_joint_states
            else 0.0
        )
        self.period = 1.0 / config.control_rate
        self.counts: Counter[str] = Counter()
        self.waited = 0.0
        self.compute_high = 0.0
        self._clock = clock
        self._started = math.nan

    def wait(self, streams: FreshJointSource) -> None:
        """Before a cycle: wait for a fresh joint state if one is due and there is time."""
        if self.max_wait > 0.0:
            room = min(self.max_wait, self.period - self.compute_high - MARGIN)
            how, waited = streams.wait_for_fresh_joint(self.fresh_age, max(room, 0.0))
            if how == "timed_out" and room <= 0.0:
                how = "no_time"
            if how != "none":  # nothing to wait for before a first joint state: bad_state
                self.counts[how] += 1
                self.waited += waited
        self._started = self._clock()

    def computed(self, now: float) -> None:
        """The cycle's command is sent at ``now`` [s]: its computation time since the wait
        enters :attr:`compute_high`."""
        if not math.isnan(self._started):
            self.compute_high = max(now - self._started, self.compute_high * DECAY)
            self._started = math.nan
