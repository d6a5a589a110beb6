"""Force arrows: which commanded contact forces are drawn, where, how long and which way."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.errors import ConfigError

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

FORCE_ARROW_MIN_N = 0.5
"""Smallest commanded contact force drawn as an arrow [N] (paper, Fig. 1 caption)."""
ARROW_M_PER_N = 0.01
"""Arrow length per newton of force [m/N]."""
ARROW_LENGTH_RANGE_M = (0.01, 0.06)
"""Shortest and longest arrow drawn [m]."""


class ForceArrows(NamedTuple):
    """The force arrows of one cycle (N of them, forces of at least the threshold)."""

    row: IntArray
    """(N,) row of each arrow in the cycle's contact arrays."""
    tip: FloatArray
    """(N, 3) arrow tips: the contact points, world frame [m]."""
    direction: FloatArray
    """(N, 3) unit directions of the forces on the object, world frame."""
    magnitude: FloatArray
    """(N,) force magnitudes [N]."""
    length: FloatArray
    """(N,) drawn arrow lengths [m]."""


def force_arrows(
    contact_p: npt.ArrayLike, contact_f: npt.ArrayLike, min_force: float = FORCE_ARROW_MIN_N
) -> ForceArrows:
    """The arrows to draw: contacts whose commanded force is at least ``min_force`` [N].

    The arrow ends at the contact point and points along the force on the object, so it shows
    the hand pushing on the object from outside.
    """
    p = np.asarray(contact_p, dtype=float).reshape(-1, 3)
    f = np.asarray(contact_f, dtype=float).reshape(-1, 3)
    if p.shape != f.shape:
        raise ConfigError(
            f"force_arrows: contact_p {p.shape} and contact_f {f.shape} differ in shape"
        )
    magnitude = np.linalg.norm(f, axis=1)
    keep = np.flatnonzero(magnitude >= min_force)
    m = magnitude[keep]
    lo, hi = ARROW_LENGTH_RANGE_M
    return ForceArrows(
        row=keep,
        tip=p[keep],
        direction=f[keep] / np.maximum(m, 1e-12)[:, None],
        magnitude=m,
        length=np.clip(ARROW_M_PER_N * m, lo, hi),
    )


def y_to(direction: FloatArray) -> FloatArray:
    """(3, 3) rotation taking +y to a unit direction."""
    R = pin.Quaternion.FromTwoVectors(np.array([0.0, 1.0, 0.0]), np.asarray(direction, dtype=float))
    return R.toRotationMatrix()
