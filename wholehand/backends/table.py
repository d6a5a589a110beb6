"""A table: a static box in the world whose top face is the support plane of the object (the
MuJoCo plug-in adds it to its scenes, :func:`wholehand_plugins.mujoco.scene.add_table`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from wholehand.errors import ConfigError

FloatArray = npt.NDArray[np.float64]

TABLE_GEOM = "table"
"""Name of the table's geom in MuJoCo scenes."""
HAND_MARGIN = 0.01
"""How far above the table top a grasp and its pre-grasp must keep the hand to be usable with
the object resting on it [m] (twice the reacher's table clearance, so the grasp is reachable)."""


@dataclass(frozen=True)
class Table:
    """A box resting in the world, world axes; its top face at height ``top`` [m].

    Attributes:
        top: height of the top face, world z [m].
        centre: (x, y) of the top face's centre, world frame [m].
        size: (x, y) side lengths of the top face [m].
        thickness: height of the box [m].
        friction: sliding friction coefficient against the object and the hand [-].
    """

    top: float = 0.0
    centre: tuple[float, float] = (0.0, 0.0)
    size: tuple[float, float] = (0.8, 0.8)
    thickness: float = 0.04
    friction: float = 0.7

    def __post_init__(self) -> None:
        values = [self.top, *self.centre, *self.size, self.thickness, self.friction]
        if len(self.centre) != 2 or len(self.size) != 2:
            raise ConfigError(f"Table: centre and size take 2 numbers each, got {self!r}")
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise ConfigError(f"Table: every value must be a finite number, got {self!r}")
        if min(*self.size, self.thickness) <= 0.0 or self.friction < 0.0:
            raise ConfigError(
                f"Table: size and thickness must be > 0 [m] and friction >= 0, got {self!r}"
            )

    @property
    def half_extents(self) -> FloatArray:
        """(3,) half side lengths of the box [m]."""
        return 0.5 * np.array([self.size[0], self.size[1], self.thickness])

    @property
    def box_centre(self) -> FloatArray:
        """(3,) centre of the box, world frame [m]."""
        return np.array([self.centre[0], self.centre[1], self.top - 0.5 * self.thickness])
