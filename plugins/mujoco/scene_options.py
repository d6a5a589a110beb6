"""The MuJoCo scene's options, names and collision bits (for
:func:`~wholehand_plugins.mujoco.scene.build_scene`).

Contact model (stated once, see :class:`SceneOptions`):

- friction: object geoms have ``priority=1``, so every hand-object contact uses the object's
  friction coefficient exactly (MuJoCo's default would take the element-wise maximum of the two
  geoms); hand geoms carry the same coefficient, used only for hand-hand contacts;
- ``condim=3``: point contacts with sliding friction only, as in the paper's contact model;
- elliptic friction cones with ``impratio=10`` (stiffer tangential response, less creep when holding
  an object by friction), Newton solver, ``implicitfast`` integration (joint damping implicit);
- timestep 1 ms and contact ``solref=(0.005, 1)``: a 5 ms time constant, 5 timesteps, stiffer
  than MuJoCo's 20 ms default so that fingertips squeezing with ~10 N penetrate by less than 1 mm.

A step whose contact solve fails is taken again (:mod:`wholehand_plugins.mujoco.step_guard`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import mujoco

from wholehand.backends.table import Table
from wholehand.errors import ConfigError

DEFAULT_TIMESTEP: float = 1e-3
"""Simulation timestep [s]. Stable for the Allegro hand at 0.2 N*m with 0.05-1 kg objects."""

OBJECT_BODY = "object"
"""Name of the object's body."""
OBJECT_JOINT = "object_free"
"""Name of the object's free joint."""

HAND_BIT = 1
"""contype bit of hand geoms."""
OBJECT_BIT = 2
"""contype bit of object geoms."""
TABLE_BIT = 4
"""contype bit of the table (it collides with the hand and the object)."""

CONES = {"elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC, "pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL}
BASES = ("fixed", "mocap", "floating")
WRIST_TARGET = "wrist_target"
"""Name of the mocap body a ``floating`` base is welded to."""
WRIST_JOINT = "wrist_free"
"""Name of a ``floating`` base's free joint."""
COLLISIONS = ("decomposition", "hull")


@dataclass(frozen=True)
class SceneOptions:
    """Physics settings of a hand-object scene (defaults justified in the module docstring)."""

    timestep: float = DEFAULT_TIMESTEP
    """Integration step [s]."""
    gravity: bool = False
    """Gravity (0, 0, -9.81) m/s^2 when True, none when False (the paper's setting)."""
    cone: Literal["elliptic", "pyramidal"] = "elliptic"
    """Friction cone of MuJoCo's contact solver."""
    impratio: float = 10.0
    """Ratio of frictional to normal constraint impedance (elliptic cones)."""
    condim: int = 3
    """Contact dimensionality: 3 = sliding friction (point contact), 4 adds torsion, 6 rolling."""
    friction: float | None = None
    """Sliding friction coefficient of hand-object contacts [-]; None: the object's own."""
    solref: tuple[float, float] = (0.005, 1.0)
    """Contact (time constant [s], damping ratio)."""
    solimp: tuple[float, float, float, float, float] = (0.9, 0.95, 0.001, 0.5, 2.0)
    """Contact impedance (MuJoCo's default)."""
    base: Literal["fixed", "mocap", "floating"] = "fixed"
    """Hand base welded at ``hand.wMb`` ("fixed"), moved kinematically ("mocap"), or free and
    held by a soft weld to a moved target ("floating": a wrist of finite stiffness, so a hand
    pressed onto an object lying on the table yields instead of crushing it)."""
    wrist_solref: tuple[float, float] = (0.01, 1.0)
    """(time constant [s], damping ratio) of a floating base's weld to its target."""
    self_collision: bool = True
    """Collide hand links with each other. Excluded always: parent-child pairs, the base with
    its children, and pairs already touching in the neutral or zero configuration."""
    collision: Literal["decomposition", "hull"] = "decomposition"
    """Mesh objects: convex parts of a CoACD decomposition, or one convex hull."""
    coacd: dict[str, Any] = field(default_factory=dict)
    """CoACD parameters overriding :data:`wholehand.models.convex.DEFAULT_PARAMS`."""
    iterations: int = 100
    """Newton solver iterations per step (upper bound)."""
    visual_mesh: bool = False
    """Also add the original object mesh as a visual-only geom (group 2), for viewers."""
    table: Table | None = None
    """A table under the object (:class:`~wholehand.backends.table.Table`); None: none."""

    def __post_init__(self) -> None:
        if not (isinstance(self.timestep, (int, float)) and 0.0 < self.timestep <= 0.01):
            raise ConfigError(f"timestep must be in (0, 0.01] s, got {self.timestep!r}")
        if self.cone not in CONES:
            raise ConfigError(f"cone must be one of {sorted(CONES)}, got {self.cone!r}")
        if self.condim not in (1, 3, 4, 6):
            raise ConfigError(f"condim must be 1, 3, 4 or 6, got {self.condim!r}")
        if self.base not in BASES:
            raise ConfigError(f"base must be one of {BASES}, got {self.base!r}")
        if self.collision not in COLLISIONS:
            raise ConfigError(f"collision must be one of {COLLISIONS}, got {self.collision!r}")
        if self.friction is not None and not (math.isfinite(self.friction) and self.friction >= 0):
            raise ConfigError(f"friction must be a finite number >= 0, got {self.friction!r}")
        if not self.solref[0] >= 2.0 * self.timestep:
            raise ConfigError(
                f"solref time constant {self.solref[0]} s must be at least twice the timestep "
                f"{self.timestep} s, else contacts are unstable; raise it or lower the timestep"
            )
