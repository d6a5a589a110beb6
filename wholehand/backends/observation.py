"""What the control loop reads each cycle: timestamped samples of the joints and the object.

Each stream carries its own stamp: the joints (``q``, ``dq`` and the base pose ``wMb``) at
``stamp_q``, the tracked object pose at ``stamp_object``. On a robot the object pose comes from a
tracker, later and slower than the joints, so the contacts of an image are estimated at the joint
configuration of the image's stamp: :class:`JointHistory` keeps the recent joint samples and
interpolates between them. A simulation fills every stream exactly (both stamps are the
simulation time); a hardware backend fills them from its messages.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numba
import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.errors import ConfigError, ObservationError
from wholehand.jit import CACHE
from wholehand.models.poses import check_pose, is_rigid

FloatArray = npt.NDArray[np.float64]

HISTORY_SAMPLES = 256
"""Joint samples a :class:`JointHistory` keeps by default (1.28 s at 200 Hz)."""


class JointHistory:
    """The most recent joint samples ``(stamp, q, wMb)``, oldest first, in a fixed ring buffer.

    Args:
        n_q: joint positions per sample.
        capacity: samples kept; the oldest is dropped when a new one arrives.
    """

    def __init__(self, n_q: int, capacity: int = HISTORY_SAMPLES) -> None:
        if int(capacity) != capacity or capacity < 1:
            raise ConfigError(f"JointHistory: capacity must be an integer >= 1, got {capacity!r}")
        self.n_q = int(n_q)
        self.capacity = int(capacity)
        self._stamp = np.zeros(self.capacity)
        self._q = np.zeros((self.capacity, self.n_q))
        self._wMb = np.zeros((self.capacity, 4, 4))
        self._count = 0
        self._next = 0

    def __len__(self) -> int:
        return self._count

    def clear(self) -> None:
        """Forget every sample."""
        self._count = 0
        self._next = 0

    def push(self, stamp: float, q: FloatArray, wMb: FloatArray) -> None:
        """Add a sample; stamps must not decrease (a sample older than the newest is an error)."""
        if self._count and stamp < self.newest_stamp:
            raise ObservationError(
                f"JointHistory: joint sample stamped {stamp!r} s is older than the newest one "
                f"({self.newest_stamp!r} s); joint stamps must not go back in time"
            )
        i = self._next
        self._stamp[i] = stamp
        self._q[i] = q
        self._wMb[i] = wMb
        self._next = (i + 1) % self.capacity
        self._count = min(self._count + 1, self.capacity)

    @property
    def newest_stamp(self) -> float:
        """Stamp of the newest sample [s]."""
        if not self._count:
            raise ObservationError("JointHistory: no joint sample yet")
        return float(self._stamp[(self._next - 1) % self.capacity])

    @property
    def oldest_stamp(self) -> float:
        """Stamp of the oldest sample kept [s]."""
        if not self._count:
            raise ObservationError("JointHistory: no joint sample yet")
        return float(self._stamp[(self._next - self._count) % self.capacity])

    def at(self, stamp: float) -> tuple[FloatArray, FloatArray]:
        """Joint positions (n_q,) and base pose (4, 4) at ``stamp`` [s].

        A stamp equal to a sample's returns that sample exactly; between two samples ``q`` is
        interpolated linearly and ``wMb`` along the SE(3) geodesic. A stamp newer than the newest
        sample gets the newest one (joint samples outrun the tracker, so that happens only by
        clock jitter).

        Raises:
            ObservationError: no sample yet, or ``stamp`` is older than the oldest sample kept.
        """
        count, capacity, stamps = self._count, self.capacity, self._stamp
        if not count:
            raise ObservationError("JointHistory: no joint sample yet")
        oldest = (self._next - count) % capacity
        if not stamp >= stamps[oldest]:
            raise ObservationError(
                f"JointHistory: stamp {stamp!r} s is older than the joint history "
                f"({stamps[oldest]!r} .. {self.newest_stamp!r} s, {count} samples); the object "
                "pose is too old for its joint configuration to be known: lengthen the history "
                "(capacity) or lower the pose latency"
            )
        # j: the samples stamped at or before `stamp` (the i-th oldest is row oldest + i).
        j = bisect.bisect_right(range(count), stamp, key=lambda i: stamps[(oldest + i) % capacity])
        a = (oldest + j - 1) % capacity
        if stamps[a] == stamp or j == count:
            return self._q[a].copy(), self._wMb[a].copy()
        b = (a + 1) % capacity
        s = (stamp - stamps[a]) / (stamps[b] - stamps[a])
        q = self._q[a] + s * (self._q[b] - self._q[a])
        A, B = pin.SE3(self._wMb[a]), pin.SE3(self._wMb[b])
        wMb = (A * pin.exp6(s * pin.log6(A.actInv(B)))).homogeneous
        return q, np.asarray(wMb)


@dataclass(frozen=True)
class Observation:
    """One reading of every stream, each with its own stamp.

    Poses are 4x4 homogeneous transforms ``aMb`` (pose of frame b in frame a) throughout wholehand.
    """

    q: FloatArray
    """(n_q,) joint positions [rad or m], in the order of the hand's Pinocchio model."""
    dq: FloatArray
    """(n_v,) joint velocities [rad/s or m/s]."""
    wMb: FloatArray
    """(4, 4) pose of the hand base (root link) in the world, at ``stamp_q``."""
    stamp_q: float
    """Time at which q, dq and wMb were measured [s]."""
    wMo: FloatArray | None
    """(4, 4) tracked pose of the object frame in the world; None until a first pose arrives."""
    stamp_object: float
    """Time at which the object pose was measured (the image time on a tracker) [s]."""
    history: JointHistory
    """Recent joint samples up to and including this one: q at any recent stamp."""

    def q_at(self, stamp: float) -> tuple[FloatArray, FloatArray]:
        """Joint positions and base pose at ``stamp`` (this sample's own at ``stamp_q``)."""
        if stamp == self.stamp_q:
            return self.q, self.wMb
        return self.history.at(stamp)

    def with_object(self, wMo: FloatArray | None, stamp_object: float) -> Observation:
        """The same joint reading with another object pose and stamp (what filters return)."""
        return Observation(
            self.q, self.dq, self.wMb, self.stamp_q, wMo, float(stamp_object), self.history
        )


@numba.njit(cache=CACHE, nogil=True)
def _usable(
    q: FloatArray, dq: FloatArray, wMb: FloatArray, wMo: FloatArray
) -> bool:  # pragma: no cover - jit
    """True when q and dq are finite and both (4, 4) poses are finite rigid transforms
    (:func:`~wholehand.models.poses.is_rigid`)."""
    for x in q:
        if not np.isfinite(x):
            return False
    for x in dq:
        if not np.isfinite(x):
            return False
    return is_rigid(wMb) and is_rigid(wMo)


def _is_vector(x: object, n: int) -> bool:
    return isinstance(x, np.ndarray) and x.dtype == np.float64 and x.shape == (n,)


def _is_pose(x: object) -> bool:
    return isinstance(x, np.ndarray) and x.dtype == np.float64 and x.shape == (4, 4)


def load_observation_check(n_q: int, n_v: int) -> None:
    """Load the compiled part of :func:`check_observation` (about a millisecond on its first
    call in a process), for a hand of ``n_q`` positions and ``n_v`` velocities."""
    _usable(np.zeros(n_q), np.zeros(n_v), np.eye(4), np.eye(4))


def check_observation(obs: Observation, n_q: int, n_v: int) -> None:
    """Raise :class:`ObservationError` naming the field at fault when ``obs`` is unusable: q or dq
    of the wrong shape or not finite, a base or object pose that is not a rigid transform, or a
    stamp that is not finite.

    The common case, float arrays that pass, is one compiled check of a few microseconds; the
    field-by-field checks below run only to name what is wrong.
    """
    wMb, wMo = obs.wMb, obs.wMo
    if (
        _is_vector(obs.q, n_q)
        and _is_vector(obs.dq, n_v)
        and _is_pose(wMb)
        and (wMo is None or _is_pose(wMo))
        and math.isfinite(obs.stamp_q)
        and math.isfinite(obs.stamp_object)
        and _usable(obs.q, obs.dq, wMb, wMb if wMo is None else wMo)
    ):
        return
    _raise_fault(obs, n_q, n_v)


def _raise_fault(obs: Observation, n_q: int, n_v: int) -> None:
    """Raise :class:`ObservationError` naming what of ``obs`` is unusable (field by field)."""
    for name, value, n in (("q", obs.q, n_q), ("dq", obs.dq, n_v)):
        kind = np.asarray(value).dtype.kind
        if kind not in "fiu":  # text that numpy would parse ("1.0") is still not a reading
            raise ObservationError(
                f"observation {name} is not numeric (numpy dtype kind {kind!r}); a backend must "
                "deliver float arrays"
            )
        arr = np.asarray(value, dtype=float)
        if arr.shape != (n,):
            raise ObservationError(
                f"observation {name} has shape {arr.shape}, the hand needs ({n},)"
            )
        if not np.isfinite(arr).all():
            raise ObservationError(f"observation {name} contains NaN or inf: {arr.tolist()}")
    for name, stamp in (("stamp_q", obs.stamp_q), ("stamp_object", obs.stamp_object)):
        if not (isinstance(stamp, int | float) and math.isfinite(stamp)):
            raise ObservationError(f"observation {name} is not a finite time: {stamp!r}")
    poses = [("wMb (hand base pose)", obs.wMb)]
    if obs.wMo is not None:
        poses.append(("wMo (object pose)", obs.wMo))
    for name, M in poses:
        try:
            check_pose(M, f"observation {name}")
        except ConfigError as err:
            raise ObservationError(str(err)) from err
