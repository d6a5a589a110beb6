"""The safety rules between the control loop and the robot's torque interface.

Every torque command the hardware backend sends passes :meth:`TorqueGuard.filter`, which applies,
in this order (the names are the statuses it counts):

1. The joint states' age, graded: older than ``joint_timeout``, the loop's torque (computed on
   a stale state) is not sent and the torque sent last is held (``joints_late``) for
   ``joint_hold``; then the held torque ramps linearly to zero over ``joint_ramp``, by the
   state's age (``joints_stale``); past that, or with no joint state yet, zero
   (``joints_lost``). A fresh
   state resumes regulation from the torque sent last (rate-limited). Holding first is what
   the drives themselves do when commands stop (a command timeout), and what ros2_control's
   controllers do implicitly (they keep commanding from the last state read); zeroing at once
   drops a held object on every gap of a busy computer.
2. ``pose_stale``: the newest object pose is older than ``pose_timeout`` -> the torque sent last
   is held and ramped linearly to zero over ``pose_ramp``; a fresh pose ends the ramp.
3. ``clamped``: every joint's torque within its limit ``tau_max``.
4. ``rate_limited``: no joint's torque changes faster than ``torque_rate`` [N*m/s] from the
   torque sent last, and no command changes it by more than one control period's worth
   (``torque_rate / control_rate``): a cycle that comes late does not send a larger step, so
   a robot that receives two commands close together (a late one, then one on time) never
   sees the torque change faster than the limit. Given the stamp each command goes out with,
   the step is also no larger than the limit times the time since the last command's stamp:
   the rate a receiver measures between stamps then holds the limit even when the loop's
   clock and the stamps' clock advanced differently between two commands (a thread preempted
   between the two readings). The first command starts from the measured effort (the torque
   the drives apply now), so a controller restarted mid-grasp resumes without a jump.

``watchdog``: when the loop sends nothing for ``watchdog`` seconds (a cycle stuck past its
deadline), :meth:`TorqueGuard.watchdog` gives the ramp from the last torque to zero, which the
backend's watchdog thread sends in the loop's place.

The guard also keeps the gaps in the joint states (:class:`JointGaps`): each run of commands
past ``joint_timeout`` after a first fresh state, how old the state got and whether a fresh one
ended it. A gap a fresh state ended came mid-run (a stalled driver, a busy computer); the one
still open when the controller stops is the run's end (the robot, or the double, stopped
publishing first). A verdict on stale joint states counts the first kind.

``stop`` and ``exit``: :meth:`TorqueGuard.ramp_down` gives the same ramp over a given time, for a
stop request (``pose_ramp``) and for the last commands of every exit (``exit_ramp``).

Times are on one monotonic clock [s], stamps on the messages' clock (the system clock) [s];
torques are (n_v,) in the hand's joint order [N*m].
"""

from __future__ import annotations

from collections import Counter

import numpy as np
import numpy.typing as npt

from wholehand.errors import ConfigError
from wholehand.ros2.config import SafetyLimits

FloatArray = npt.NDArray[np.float64]


class JointGaps:
    """The gaps in the joint states a :class:`TorqueGuard` has seen: each run of commands
    with the newest state older than ``joint_timeout``, after the first fresh state."""

    def __init__(self) -> None:
        self.recovered = 0
        """Gaps a fresh joint state ended."""
        self.recovered_past_hold = 0
        """Of those, gaps that outlasted ``joint_hold``: the torque ramped (``joints_stale``)
        or was zero (``joints_lost``) before the state came back."""
        self.longest_recovered = 0.0
        """The oldest the joint state got in a gap that ended [s]."""
        self.open_age = 0.0
        """How old the joint state is in the gap still open [s] (0: none is)."""
        self.open_status = ""
        """The furthest rule the open gap reached (``joints_late``, ``joints_stale``,
        ``joints_lost``; empty: no gap is open)."""
        self._seen_fresh = False

    def late(self, age: float, status: str) -> None:
        """A command with the joint state ``age`` [s] old, decided by ``status``."""
        if not self._seen_fresh:
            return  # before the first state: starting, not a gap
        self.open_age = max(self.open_age, age)
        if RANK[status] > RANK[self.open_status]:
            self.open_status = status

    def fresh(self) -> None:
        """A command on a fresh joint state: any open gap ended."""
        self._seen_fresh = True
        if self.open_status:
            self.recovered += 1
            self.recovered_past_hold += self.open_status != "joints_late"
            self.longest_recovered = max(self.longest_recovered, self.open_age)
            self.open_age, self.open_status = 0.0, ""

    def summary(self) -> dict[str, float | int | str]:
        """The counts, JSON-ready."""
        return {
            "recovered": self.recovered,
            "recovered_past_hold": self.recovered_past_hold,
            "longest_recovered_s": round(self.longest_recovered, 6),
            "open_at_end": self.open_status,
            "open_age_s": round(self.open_age, 6),
        }


RANK = {"": 0, "joints_late": 1, "joints_stale": 2, "joints_lost": 3}
"""How far past ``joint_timeout`` each rule of a gap lies."""


class TorqueGuard:
    """Applies the safety rules to each torque command.

    Args:
        tau_max: (n_v,) torque limit per joint [N*m] (0: the joint gets no torque).
        limits: the rules' times and rates.
        period: the control period [s]: the longest time one command's rate-limited step
            covers (None: no such bound, the step grows with the time since the last command).
    """

    def __init__(
        self, tau_max: npt.ArrayLike, limits: SafetyLimits, period: float | None = None
    ) -> None:
        if period is not None and not (np.isfinite(period) and period > 0.0):
            raise ConfigError(f"TorqueGuard: period must be > 0 [s], got {period!r}")
        self.max_step_time = np.inf if period is None else float(period)
        self.tau_max = np.asarray(tau_max, dtype=float).copy()
        if self.tau_max.ndim != 1 or (self.tau_max < 0.0).any():
            raise ConfigError("TorqueGuard: tau_max must be (n_v,) values >= 0 [N*m]")
        self._lower = -self.tau_max
        self.limits = limits
        self.counts: Counter[str] = Counter()
        """Commands per rule that changed them (``ok`` when none did)."""
        self.last: FloatArray | None = None
        """(n_v,) the torque sent last [N*m]; None before the first."""
        self.t_last = 0.0
        self.stamp_last: float | None = None
        """The stamp the torque sent last went out with [s]; None: not given."""
        self._ramp_from: FloatArray | None = None
        self._ramp_start = 0.0
        self._held: FloatArray | None = None  # the torque held since the joint states stopped
        self.gaps = JointGaps()
        """The gaps in the joint states so far."""

    def start_from(self, effort: FloatArray | None, now: float) -> None:
        """Take the measured effort (n_v,) [N*m] (None: zero) as the torque sent last, so that
        the first command is rate-limited from it."""
        if self.last is None:
            start = np.zeros_like(self.tau_max) if effort is None else np.asarray(effort)
            self.last = np.clip(start, -self.tau_max, self.tau_max)
            self.t_last = now

    def filter(
        self,
        tau: FloatArray,
        now: float,
        joint_age: float,
        pose_age: float,
        stamp: float | None = None,
    ) -> tuple[FloatArray, str]:
        """The torque to send for the loop's ``tau`` (n_v,) at time ``now`` [s], given the ages of
        the newest joint state and object pose [s] (inf: none yet) and the stamp the torque will
        go out with [s] (None: not stamped); and the rule that decided (``ok`` when none changed
        it)."""
        limits = self.limits
        if not joint_age <= limits.joint_timeout:
            self._ramp_from = None
            held, status = self._without_joints(joint_age)
            self.gaps.late(joint_age, status)
            return self._sent(held, now, status, stamp)
        self._held = None
        self.gaps.fresh()
        self.start_from(None, now)
        if not pose_age <= limits.pose_timeout:
            return self._sent(self._ramp(now), now, "pose_stale", stamp)
        self._ramp_from = None
        status = "ok"
        # np.clip's results; its wrapper and np.array_equal's cost more than the arithmetic.
        out = np.minimum(np.maximum(tau, self._lower), self.tau_max)
        if not (out == tau).all():
            status = "clamped"
        assert self.last is not None
        elapsed = min(now - self.t_last, self.max_step_time)
        if stamp is not None and self.stamp_last is not None:
            elapsed = min(elapsed, stamp - self.stamp_last)
        step = limits.torque_rate * max(elapsed, 0.0)
        limited = np.minimum(np.maximum(out, self.last - step), self.last + step)
        if not (limited == out).all():
            status = "rate_limited"
        return self._sent(limited, now, status, stamp)

    def _without_joints(self, joint_age: float) -> tuple[FloatArray, str]:
        """The torque and status while the joint states are ``joint_age`` [s] old (past
        ``joint_timeout``): held, ramped by age, or zero (module docstring)."""
        limits = self.limits
        if self._held is None:
            self._held = np.zeros_like(self.tau_max) if self.last is None else self.last
        past_hold = joint_age - limits.joint_timeout - limits.joint_hold
        if not past_hold <= limits.joint_ramp:
            return np.zeros_like(self.tau_max), "joints_lost"
        if past_hold <= 0.0:
            return self._held, "joints_late"
        return self._held * (1.0 - past_hold / limits.joint_ramp), "joints_stale"

    def watchdog(self, now: float, stamp: float | None = None) -> FloatArray:
        """The torque the watchdog sends when the loop is late: the last torque ramped to zero
        over ``pose_ramp`` from the first late call on (``stamp``: as :meth:`filter`'s)."""
        return self._sent(self._ramp(now), now, "watchdog", stamp)[0]

    def ramp_down(
        self, now: float, duration: float, status: str, stamp: float | None = None
    ) -> FloatArray:
        """The last torque ramped linearly to zero over ``duration`` [s] from the first call of
        a ramp on (counted as ``status``; ``stamp``: as :meth:`filter`'s); a command through
        :meth:`filter` ends the ramp."""
        return self._sent(self._ramp(now, duration), now, status, stamp)[0]

    def _ramp(self, now: float, duration: float | None = None) -> FloatArray:
        if self._ramp_from is None:
            self._ramp_from = np.zeros_like(self.tau_max) if self.last is None else self.last
            self._ramp_start = now
        duration = self.limits.pose_ramp if duration is None else duration
        left = max(0.0, 1.0 - (now - self._ramp_start) / duration) if duration > 0.0 else 0.0
        return self._ramp_from * left

    def _sent(
        self, tau: FloatArray, now: float, status: str, stamp: float | None
    ) -> tuple[FloatArray, str]:
        self.counts[status] += 1
        self.last = tau
        self.t_last = now
        self.stamp_last = stamp
        return tau, status
