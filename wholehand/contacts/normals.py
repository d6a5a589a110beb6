"""The loop's check that contact normals are unit vectors, compiled (it runs every cycle)."""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

from wholehand.jit import CACHE

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def unit_normals(n_world: FloatArray, tol: float) -> tuple[BoolArray, bool]:  # pragma: no cover
    """Which of the (N, 3) normals are unit vectors (``| |n|^2 - 1 | < tol``, False for NaN),
    and whether all are. ``|n|^2`` is summed as numpy's ``einsum`` sums it here (two lanes)."""
    unit = np.empty(n_world.shape[0], dtype=np.bool_)
    every = True
    for i in range(n_world.shape[0]):
        x, y, z = n_world[i, 0], n_world[i, 1], n_world[i, 2]
        unit[i] = abs((x * x + z * z) + y * y - 1.0) < tol
        every = every and unit[i]
    return unit, every
