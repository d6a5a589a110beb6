"""Where an arm may reach: a box for the palm, a box for the object, and an optional table.

On a robot the stage machine keeps the palm's targets inside :attr:`Workspace.palm` and sends
the arm home while the object is outside :attr:`Workspace.object` (paper Sec. V-D: the robot
returned to its default pose when the object left its workspace). Boxes are axis-aligned in the
world frame [m].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from wholehand.backends.table import Table
from wholehand.errors import ConfigError

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Box:
    """An axis-aligned box, world frame: ``lower <= p <= upper`` per axis [m]."""

    lower: tuple[float, float, float]
    upper: tuple[float, float, float]
    name: str = "box"
    """What the box is, for errors (e.g. ``"[workspace] palm"``)."""

    def __post_init__(self) -> None:
        lower, upper = self.lower, self.upper
        if len(lower) != 3 or len(upper) != 3:
            raise ConfigError(f"{self.name}: lower and upper take 3 numbers [m] each")
        values = [*lower, *upper]
        if not all(isinstance(v, int | float) and math.isfinite(v) for v in values):
            raise ConfigError(f"{self.name}: every bound must be a finite number [m], got {self}")
        if any(lo >= hi for lo, hi in zip(lower, upper, strict=True)):
            raise ConfigError(
                f"{self.name}: each lower bound must be below its upper bound, got lower="
                f"{list(lower)} upper={list(upper)}"
            )

    def contains(self, p: FloatArray) -> bool:
        """True if the (3,) point ``p`` [m] is inside (or on) the box."""
        return bool(np.all(p >= self.lower) and np.all(p <= self.upper))

    def clamp(self, p: FloatArray) -> FloatArray:
        """(3,) the point of the box nearest ``p`` [m]."""
        return np.minimum(np.maximum(p, self.lower), self.upper)


@dataclass(frozen=True)
class Workspace:
    """The boxes of an arm's workspace and the table it works above."""

    palm: Box
    """The palm's targets are kept in this box."""
    object: Box
    """The arm reaches for an object whose origin is in this box; outside it the arm goes home."""
    table: Table | None = None
    """A table the reacher keeps the hand above (None: none)."""
