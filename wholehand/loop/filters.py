"""Observation filters: change what the controller sees of the object, never the simulation.

A filter maps each cycle's observation to the one the stages see, in the order given to the
loop; the backend, the grasp-loss check and the recorder keep the true state. They model a
tracker: a constant pose error (paper Sec. IV-B-2), measurement noise, a frame rate with a
latency, dropouts. Filters only change the object stream (``wMo``, ``stamp_object``); joint
readings pass unchanged.
"""

from __future__ import annotations

import abc
from collections import deque
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.backends.observation import Observation
from wholehand.errors import ConfigError

FloatArray = npt.NDArray[np.float64]

_EPS = 1e-9
"""Slack on time comparisons [s], so that a frame due at 1/30 s is not missed by rounding."""


class ObservationFilter(abc.ABC):
    """Maps the observation of a cycle at backend time ``t`` to what the controller sees."""

    @abc.abstractmethod
    def apply(self, obs: Observation, t: float) -> Observation:
        """The filtered observation (``obs`` itself when nothing changes)."""


class ConstantPoseError(ObservationFilter):
    """The object pose seen as ``wMo @ offset``: a constant error in the object frame.

    Args:
        offset: (4, 4) rigid transform in the object frame (see
            :func:`wholehand.trials.trial.pose_error_offset`).
    """

    def __init__(self, offset: FloatArray) -> None:
        self.offset = np.asarray(offset, dtype=float)

    def apply(self, obs: Observation, t: float) -> Observation:
        if obs.wMo is None:
            return obs
        return obs.with_object(obs.wMo @ self.offset, obs.stamp_object)


class PoseNoise(ObservationFilter):
    """White measurement noise on each new pose (a new ``stamp_object``), held until the next.

    The rotation is by an angle ~ N(0, ``rot_deg``) about a uniformly random axis through
    ``centre`` (object frame, e.g. the centre of mass), the translation ~ N(0, ``trans_mm``) per
    world axis.

    Args:
        trans_mm: standard deviation of the translation per axis [mm], >= 0.
        rot_deg: standard deviation of the rotation angle [deg], >= 0.
        seed: seeds the noise.
        centre: (3,) point of the object frame the rotation is about [m].
    """

    def __init__(
        self,
        trans_mm: float = 0.0,
        rot_deg: float = 0.0,
        seed: int = 0,
        centre: npt.ArrayLike = (0.0, 0.0, 0.0),
    ) -> None:
        for name, value in (("trans_mm", trans_mm), ("rot_deg", rot_deg)):
            if not (isinstance(value, int | float) and 0.0 <= value < np.inf):
                raise ConfigError(f"PoseNoise: {name} must be finite and >= 0, got {value!r}")
        self.sigma_t = 1e-3 * float(trans_mm)
        self.sigma_r = np.deg2rad(float(rot_deg))
        self.centre = np.asarray(centre, dtype=float).reshape(3)
        self._rng = np.random.default_rng(seed)
        self._stamp: float | None = None
        self._offset = np.eye(4)
        self._shift = np.zeros(3)

    def apply(self, obs: Observation, t: float) -> Observation:
        if obs.wMo is None:
            return obs
        if obs.stamp_object != self._stamp:
            self._stamp = obs.stamp_object
            axis = self._rng.standard_normal(3)
            R = pin.exp3(self._rng.normal(scale=self.sigma_r) * axis / np.linalg.norm(axis))
            self._offset = np.eye(4)
            self._offset[:3, :3] = R
            self._offset[:3, 3] = self.centre - R @ self.centre
            self._shift = self._rng.normal(scale=self.sigma_t, size=3)
        seen = obs.wMo @ self._offset
        seen[:3, 3] += self._shift
        return obs.with_object(seen, obs.stamp_object)


class PoseTracker(ObservationFilter):
    """A tracker at a frame rate with a latency: the pose of each frame arrives late.

    A frame is taken on the first cycle at or after each multiple of ``1 / rate_hz`` (from the
    first cycle); its pose, stamped with the frame's time, is delivered ``latency_s`` later
    (on the first cycle at or after that time) and stays until the next delivery. The first
    frame is delivered at once: the loop starts with the tracker locked on the object.

    Args:
        rate_hz: frame rate [Hz], > 0.
        latency_s: delay from a frame's time to its delivery [s], >= 0.
    """

    def __init__(self, rate_hz: float = 30.0, latency_s: float = 0.033) -> None:
        if not (isinstance(rate_hz, int | float) and 0.0 < rate_hz < np.inf):
            raise ConfigError(f"PoseTracker: rate_hz must be finite and > 0, got {rate_hz!r}")
        if not (isinstance(latency_s, int | float) and 0.0 <= latency_s < np.inf):
            raise ConfigError(
                f"PoseTracker: latency_s must be finite and >= 0 [s], got {latency_s!r}"
            )
        self.period = 1.0 / float(rate_hz)
        self.latency = float(latency_s)
        self._next_frame: float | None = None
        self._pending: deque[tuple[float, FloatArray]] = deque()
        self._current: tuple[float, FloatArray] | None = None

    def apply(self, obs: Observation, t: float) -> Observation:
        if obs.wMo is None:
            if self._current is None:
                return obs
            return obs.with_object(self._current[1], self._current[0])
        if self._next_frame is None:
            self._current = (obs.stamp_object, obs.wMo.copy())
            self._next_frame = obs.stamp_object + self.period
        elif obs.stamp_object + _EPS >= self._next_frame:
            self._pending.append((obs.stamp_object, obs.wMo.copy()))
            while self._next_frame <= obs.stamp_object + _EPS:
                self._next_frame += self.period
        while self._pending and self._pending[0][0] + self.latency <= t + _EPS:
            self._current = self._pending.popleft()
        assert self._current is not None
        stamp, wMo = self._current
        return obs.with_object(wMo, stamp)


class PosePredictor(ObservationFilter):
    """Carries the newest pose forward to the joint state's time at the object's velocity
    between the last two poses (constant linear velocity of the object frame's origin and
    constant angular velocity): what compensates a tracker's latency while the object moves.

    The prediction reaches at most ``horizon_s`` past the newest pose's stamp, and the seen
    pose is stamped with the time it was carried to. Two poses further apart than
    ``max_gap_s`` (a dropout) give no velocity: the newest pose stays as it is until the next.

    Args:
        horizon_s: longest prediction [s], > 0.
        max_gap_s: longest time between two poses whose difference is a velocity [s], > 0.
    """

    def __init__(self, horizon_s: float = 0.1, max_gap_s: float = 0.2) -> None:
        for name, value in (("horizon_s", horizon_s), ("max_gap_s", max_gap_s)):
            if not (isinstance(value, int | float) and 0.0 < value < np.inf):
                raise ConfigError(
                    f"PosePredictor: {name} must be finite and > 0 [s], got {value!r}"
                )
        self.horizon, self.max_gap = float(horizon_s), float(max_gap_s)
        self._frames: deque[tuple[float, FloatArray]] = deque(maxlen=2)
        self._velocity: tuple[FloatArray, FloatArray] | None = None

    def apply(self, obs: Observation, t: float) -> Observation:
        if obs.wMo is None:
            return obs
        stamp = obs.stamp_object
        if not self._frames or stamp > self._frames[-1][0]:
            self._frames.append((stamp, obs.wMo.copy()))
            self._velocity = self._frame_velocity()
        if self._velocity is None or stamp != self._frames[-1][0]:
            return obs
        ahead = min(max(obs.stamp_q - stamp, 0.0), self.horizon)
        v, omega = self._velocity
        seen = np.eye(4)
        seen[:3, :3] = pin.exp3(omega * ahead) @ obs.wMo[:3, :3]
        seen[:3, 3] = obs.wMo[:3, 3] + v * ahead
        return obs.with_object(seen, stamp + ahead)

    def _frame_velocity(self) -> tuple[FloatArray, FloatArray] | None:
        """Linear velocity of the origin [m/s] and angular velocity [rad/s], world axes,
        between the last two poses; None with fewer, or across a gap."""
        if len(self._frames) < 2:
            return None
        (t0, M0), (t1, M1) = self._frames
        dt = t1 - t0
        if not 0.0 < dt <= self.max_gap:
            return None
        omega = pin.log3(M1[:3, :3] @ M0[:3, :3].T) / dt
        return (M1[:3, 3] - M0[:3, 3]) / dt, omega


class PoseDropout(ObservationFilter):
    """No new pose during given intervals of backend time: the last one before stays, with its
    stamp (so its age shows); a dropout from the start gives no pose at all.

    Args:
        intervals: ``(start, duration)`` pairs [s] of backend time.
    """

    def __init__(self, intervals: Sequence[tuple[float, float]]) -> None:
        checked = []
        for item in intervals:
            start, duration = (float(v) for v in item)
            if not (np.isfinite(start) and np.isfinite(duration) and duration >= 0.0):
                raise ConfigError(
                    f"PoseDropout: interval {item!r} must be (start, duration) with a finite "
                    "start and a finite duration >= 0 [s]"
                )
            checked.append((start, start + duration))
        self.intervals = tuple(checked)
        self._last: tuple[float, FloatArray] | None = None

    def apply(self, obs: Observation, t: float) -> Observation:
        if any(a - _EPS <= t < b - _EPS for a, b in self.intervals):
            if self._last is None:
                return obs.with_object(None, obs.stamp_object)
            return obs.with_object(self._last[1], self._last[0])
        if obs.wMo is not None:
            self._last = (obs.stamp_object, obs.wMo)
        return obs
