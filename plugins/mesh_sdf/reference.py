"""Reference forms of the contact estimator's steps, for tests and offline use (never the
control loop, whose fused kernel :func:`~wholehand_plugins.mesh_sdf.kernels.mesh_sdf_contacts`
does the same work in one pass)."""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

from wholehand.jit import CACHE
from wholehand.models.sdf_lookup import grid_tuples, sdf_value_and_gradient

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


def top_k_per_link(link: IntArray, distance: npt.NDArray[np.floating], k: int) -> IntArray:
    """Indices of at most ``k`` rows per link, smallest distance first (stable, no Python loop).

    Args:
        link: (M,) link index of each candidate.
        distance: (M,) signed distance of each candidate [m].
        k: maximum rows kept per link (>= 1).

    Returns:
        Indices into the candidates, ordered by link then distance.
    """
    if link.size == 0:
        return np.zeros(0, dtype=np.intp)
    order = np.lexsort((distance, link))
    sorted_link = link[order]
    starts = np.flatnonzero(np.r_[True, sorted_link[1:] != sorted_link[:-1]])
    group_start = np.repeat(starts, np.diff(np.r_[starts, sorted_link.size]))
    rank = np.arange(sorted_link.size) - group_start
    return order[rank < k]


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def sdf_query(
    values: npt.NDArray[np.float32],
    dims: npt.NDArray[np.int64],
    geom: FloatArray,
    points_obj: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Distances (P,) [m] and unit gradients (P, 3) at (P, 3) object-frame points [m]: the
    batch form of :func:`sdf_value_and_gradient` (for tests and offline use)."""
    shape, g = grid_tuples(dims, geom)
    n = points_obj.shape[0]
    dist = np.empty(n)
    grad = np.empty((n, 3))
    for i in range(n):
        d, gx, gy, gz = sdf_value_and_gradient(
            values, shape, g, points_obj[i, 0], points_obj[i, 1], points_obj[i, 2]
        )
        dist[i] = d
        grad[i, 0] = gx
        grad[i, 1] = gy
        grad[i, 2] = gz
    return dist, grad
