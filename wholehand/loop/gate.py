"""A plausibility gate on observations: a one-off glitch is refused, a sustained change accepted.

A well-formed observation (finite, rigid poses) can still be impossible: a joint far outside its
limits, an object that jumped farther than it can move in the time between two poses, an object
outside the hand's workspace. The gate refuses such an observation with an
:class:`~wholehand.errors.ObservationError` (the loop keeps the last feasible command, status
``bad_state``), so one bad tracker frame never drives the hand. When the same check keeps failing
for ``accept_after`` consecutive cycles the change is real (the object was moved, a joint
re-calibrated): it is accepted, becomes the new reference, and is counted in
:attr:`ObservationGate.accepted`.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from wholehand.backends.observation import Observation
from wholehand.errors import ConfigError, ObservationError
from wholehand.models.hand import HandModel


@dataclass(frozen=True)
class GateLimits:
    """What the gate accepts."""

    joint_margin: float = 0.2
    """Allowed excursion beyond a joint's limits [rad or m] (MuJoCo's soft limits and pressed
    fingers go a few mrad past them)."""
    max_speed: float = 2.0
    """Largest object speed between two poses [m/s]."""
    max_angular_speed: float = 20.0
    """Largest object angular speed between two poses [rad/s]."""
    workspace_radius: float = 1.0
    """Largest distance of the object origin from the hand base [m]."""
    accept_after: int = 20
    """Consecutive failures of one check after which the change is accepted (0.1 s at 200 Hz)."""

    def __post_init__(self) -> None:
        for name in ("joint_margin", "max_speed", "max_angular_speed", "workspace_radius"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and 0.0 <= value < np.inf):
                raise ConfigError(f"GateLimits: {name} must be finite and >= 0, got {value!r}")
        if int(self.accept_after) != self.accept_after or self.accept_after < 1:
            raise ConfigError(
                f"GateLimits: accept_after must be an integer >= 1, got {self.accept_after!r}"
            )


class ObservationGate:
    """Refuses implausible observations until they persist (see the module docstring).

    Args:
        hand: the hand (joint limits).
        limits: the thresholds.
    """

    def __init__(self, hand: HandModel, limits: GateLimits | None = None) -> None:
        self.limits = limits or GateLimits()
        self._lower = hand.q_lower - self.limits.joint_margin
        self._upper = hand.q_upper + self.limits.joint_margin
        self._names = list(hand.joint_names)
        self._reference: tuple[float, np.ndarray] | None = None
        self._failing: dict[str, int] = {}
        self.refused: Counter[str] = Counter()
        """Refused observations per check (``joints``, ``jump``, ``workspace``)."""
        self.accepted: Counter[str] = Counter()
        """Sustained changes accepted per check."""

    def check(self, obs: Observation) -> None:
        """Raise :class:`ObservationError` naming the implausible value, unless the same check
        has failed ``accept_after`` times in a row (then accept it)."""
        refused = self._refused(self._failures(obs))
        if refused:
            raise ObservationError("implausible observation: " + "; ".join(refused))
        if obs.wMo is not None:
            self._reference = (obs.stamp_object, obs.wMo)

    def _failures(self, obs: Observation) -> dict[str, str]:
        """Each check ``obs`` fails, with why."""
        failures: dict[str, str] = {}
        wMo, limits = obs.wMo, self.limits
        ref = self._reference
        dt = 0.0 if ref is None or wMo is None else obs.stamp_object - ref[0]
        outside, distance, moved, turned = _measures(
            np.asarray(obs.q, dtype=np.float64),
            self._lower,
            self._upper,
            wMo,
            obs.wMb,
            None if ref is None or dt <= 0.0 else ref[1],
        )
        if outside >= 0:
            i, q = outside, float(obs.q[outside])
            failures["joints"] = (
                f"joint {self._names[i]!r} at {q:.3f} is outside its limits "
                f"[{self._lower[i] + limits.joint_margin:.3f}, "
                f"{self._upper[i] - limits.joint_margin:.3f}] by more than "
                f"{limits.joint_margin} (GateLimits.joint_margin)"
            )
        if wMo is not None:
            if distance > limits.workspace_radius:
                failures["workspace"] = (
                    f"object {distance:.3f} m from the hand base, beyond "
                    f"{limits.workspace_radius} m (GateLimits.workspace_radius)"
                )
            jump = self._jump(dt, moved, turned)
            if jump:
                failures["jump"] = jump
        return failures

    def _refused(self, failures: dict[str, str]) -> list[str]:
        """Count ``failures`` against the checks' runs of failures; the reasons of those not
        yet sustained for ``accept_after`` observations (refused)."""
        limits = self.limits
        for name in list(self._failing):
            if name not in failures:
                del self._failing[name]
        refused = []
        for name, reason in failures.items():
            count = self._failing[name] = self._failing.get(name, 0) + 1
            if count < limits.accept_after:
                self.refused[name] += 1
                refused.append(reason)
            elif count == limits.accept_after:  # sustained: accepted while it lasts
                self.accepted[name] += 1
        return refused

    def _jump(self, dt: float, moved: float, turned: float) -> str:
        """The reason a pose ``dt`` [s] after the reference, ``moved`` [m] and ``turned``
        [rad] from it, is too fast ("" when it is not, or when it is not later)."""
        if math.isnan(moved) or dt <= 0.0:
            return ""
        speed, turn = moved / dt, turned / dt
        if speed > self.limits.max_speed:
            return (
                f"object moved at {speed:.2f} m/s between poses {dt * 1e3:.1f} ms apart, above "
                f"{self.limits.max_speed} m/s (GateLimits.max_speed)"
            )
        if turn > self.limits.max_angular_speed:
            return (
                f"object turned at {turn:.1f} rad/s between poses {dt * 1e3:.1f} ms apart, above "
                f"{self.limits.max_angular_speed} rad/s (GateLimits.max_angular_speed)"
            )
        return ""


def _measures(
    q: npt.NDArray[np.float64],
    lower: npt.NDArray[np.float64],
    upper: npt.NDArray[np.float64],
    wMo: npt.NDArray[np.float64] | None,
    wMb: npt.NDArray[np.float64],
    wMo_ref: npt.NDArray[np.float64] | None,
) -> tuple[int, float, float, float]:
    """What the gate checks: the first joint outside ``[lower, upper]`` (-1 for none), the
    object's distance from the hand base [m], and how far it moved [m] and turned [rad] since
    ``wMo_ref`` (NaN where a pose is None). On Python floats: a few dozen operations, cheaper
    than as many numpy calls."""
    outside = np.flatnonzero((q < lower) | (q > upper))
    first = int(outside[0]) if outside.size else -1
    if wMo is None:
        return first, math.nan, math.nan, math.nan
    o, b = wMo.tolist(), wMb.tolist()
    distance = math.dist((o[0][3], o[1][3], o[2][3]), (b[0][3], b[1][3], b[2][3]))
    if wMo_ref is None:
        return first, distance, math.nan, math.nan
    r = wMo_ref.tolist()
    moved = math.dist((o[0][3], o[1][3], o[2][3]), (r[0][3], r[1][3], r[2][3]))
    # The angle of R_ref^T R from its cosine (the trace) and its sine (the skew part).
    m = [
        [r[0][a] * o[0][c] + r[1][a] * o[1][c] + r[2][a] * o[2][c] for c in range(3)]
        for a in range(3)
    ]
    cos = 0.5 * (m[0][0] + m[1][1] + m[2][2] - 1.0)
    sin = 0.5 * math.hypot(m[2][1] - m[1][2], m[0][2] - m[2][0], m[1][0] - m[0][1])
    return first, distance, moved, math.atan2(sin, cos)
