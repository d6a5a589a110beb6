"""Compiled point lookups of a :class:`~wholehand.models.sdf.SignedDistanceGrid`, for numba
kernels that walk their points one at a time (the contact estimator's cycle, the grasp
synthesis energy).

SDF lookups reproduce :meth:`SignedDistanceGrid.query` and :meth:`~SignedDistanceGrid.
query_with_gradient` (``wholehand.models.sdf``) operation for operation, so the results are equal
to the last bit for equal object-frame points: the coordinates are clamped to the grid box, the
eight corner values (float32) are interpolated in float32 along z, then y, then x, and points
outside the box get their distance to the box added (the gradient of that term replaces the
clamped axes' components). NaN coordinates give NaN distances and gradients, as there.

The SDF grid is passed as three arguments (see :func:`grid_arguments`):

- ``values``: (nx * ny * nz,) float32 node values [m], C order (x slowest).
- ``dims``: (3,) int64 node counts (nx, ny, nz).
- ``geom``: (5,) float64 ``(1 / spacing [1/m], spacing [m], *origin / spacing [cells])``.

The per-point lookups take ``dims`` and ``geom`` as tuples of scalars (``shape``, ``geom``):
arrays there would be reference-counted (atomically) on every inlined call. They index the grid
with unsigned integers, which spares numba's negative-index wraparound on each of the 8 reads
(the indices are in range by the clamping).
"""

from __future__ import annotations

import math
from typing import Protocol

import numba
import numpy as np
import numpy.typing as npt

from wholehand.jit import CACHE

FloatArray = npt.NDArray[np.float64]


class Grid(Protocol):
    """What :func:`grid_arguments` reads of a :class:`~wholehand.models.sdf.SignedDistanceGrid`
    (which uses these lookups itself, so this module does not import it)."""

    @property
    def values(self) -> npt.NDArray[np.float32]: ...
    @property
    def origin(self) -> FloatArray: ...
    @property
    def spacing(self) -> float: ...
    @property
    def shape(self) -> tuple[int, int, int]: ...


_F32_TINY = np.float32(1e-30)  # floor of the gradient norm, as in SignedDistanceGrid


def grid_arguments(
    sdf: Grid,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int64], FloatArray]:
    """The kernels' view of an SDF grid: ``(values, dims, geom)`` (module docstring).

    ``values`` is a read-only view of the grid's own array (no copy). The derived constants are
    computed exactly as :class:`SignedDistanceGrid` computes its own, so lookups agree bit for bit.
    """
    values = sdf.values.reshape(-1)
    dims = np.array(sdf.shape, dtype=np.int64)
    geom = np.array([1.0 / sdf.spacing, sdf.spacing, *(sdf.origin / sdf.spacing)])
    return values, dims, geom


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def grid_tuples(
    dims: npt.NDArray[np.int64], geom: FloatArray
) -> tuple[tuple[int, int, int], tuple[float, float, float, float, float]]:
    """``dims`` and ``geom`` as tuples of scalars, for the per-point lookups."""
    return (dims[0], dims[1], dims[2]), (geom[0], geom[1], geom[2], geom[3], geom[4])


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _clamp_axis(u: float, n: int) -> tuple[float, float]:
    """Grid coordinate ``u`` [cells] clamped to [0, n - 1], and the lower corner of its cell,
    at most n - 2. A NaN ``u`` stays NaN and gets the (safe) cell n - 2."""
    upper = float(n) - 1.0
    uc = u
    if u < 0.0:
        uc = 0.0
    elif u > upper:
        uc = upper
    cell = np.floor(uc)
    if not cell <= upper - 1.0:  # also for NaN, as np.fmin(NaN, upper - 1)
        cell = upper - 1.0
    return uc, cell


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def sdf_value(
    values: npt.NDArray[np.float32],
    shape: tuple[int, int, int],
    geom: tuple[float, float, float, float, float],
    x: float,
    y: float,
    z: float,
) -> float:
    """Signed distance [m] at the object-frame point (x, y, z) [m]; equal to
    :meth:`SignedDistanceGrid.query` (trilinear in float32, plus the distance outside the box)."""
    nx, ny, nz = shape
    inv_spacing, spacing, ox, oy, oz = geom
    ux = x * inv_spacing - ox
    uy = y * inv_spacing - oy
    uz = z * inv_spacing - oz
    ucx, cx = _clamp_axis(ux, nx)
    ucy, cy = _clamp_axis(uy, ny)
    ucz, cz = _clamp_axis(uz, nz)
    tx = np.float32(ucx - cx)
    ty = np.float32(ucy - cy)
    tz = np.float32(ucz - cz)
    i = np.uint64(int(cx) * (ny * nz) + int(cy) * nz + int(cz))
    one = np.uint64(1)
    j = i + np.uint64(nz)  # y + 1
    a0 = values[i] + tz * (values[i + one] - values[i])  # x0 y0
    a1 = values[j] + tz * (values[j + one] - values[j])  # x0 y1
    i += np.uint64(ny * nz)
    j += np.uint64(ny * nz)
    a2 = values[i] + tz * (values[i + one] - values[i])  # x1 y0
    a3 = values[j] + tz * (values[j + one] - values[j])  # x1 y1
    b0 = a0 + ty * (a1 - a0)
    b1 = a2 + ty * (a3 - a2)
    d = np.float64(b0 + tx * (b1 - b0))
    ex, ey, ez = ucx - ux, ucy - uy, ucz - uz
    if ex != 0.0 or ey != 0.0 or ez != 0.0:  # outside the box (or NaN)
        d += math.sqrt(ex * ex + ey * ey + ez * ez) * spacing
    return float(d)


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def sdf_value_and_gradient(
    values: npt.NDArray[np.float32],
    shape: tuple[int, int, int],
    geom: tuple[float, float, float, float, float],
    x: float,
    y: float,
    z: float,
) -> tuple[float, float, float, float]:
    """Signed distance [m] and unit gradient (gx, gy, gz) (object frame) at the object-frame
    point (x, y, z) [m]; equal to :meth:`SignedDistanceGrid.query_with_gradient`."""
    nx, ny, nz = shape
    inv_spacing, spacing, ox, oy, oz = geom
    ux = x * inv_spacing - ox
    uy = y * inv_spacing - oy
    uz = z * inv_spacing - oz
    ucx, cx = _clamp_axis(ux, nx)
    ucy, cy = _clamp_axis(uy, ny)
    ucz, cz = _clamp_axis(uz, nz)
    tx = np.float32(ucx - cx)
    ty = np.float32(ucy - cy)
    tz = np.float32(ucz - cz)
    i = np.uint64(int(cx) * (ny * nz) + int(cy) * nz + int(cz))
    one = np.uint64(1)
    j = i + np.uint64(nz)
    ez0 = values[i + one] - values[i]  # z-differences per (x, y) edge
    ez1 = values[j + one] - values[j]
    a0 = values[i] + tz * ez0
    a1 = values[j] + tz * ez1
    i += np.uint64(ny * nz)
    j += np.uint64(ny * nz)
    ez2 = values[i + one] - values[i]
    ez3 = values[j + one] - values[j]
    a2 = values[i] + tz * ez2
    a3 = values[j] + tz * ez3
    ey0 = a1 - a0  # y-differences per x
    ey1 = a3 - a2
    b0 = a0 + ty * ey0
    b1 = a2 + ty * ey1
    gx = b1 - b0
    d = np.float64(b0 + tx * gx)
    gy = ey0 + tx * (ey1 - ey0)
    gz0 = ez0 + ty * (ez1 - ez0)
    gz1 = ez2 + ty * (ez3 - ez2)
    gz = gz0 + tx * (gz1 - gz0)
    ex, ey, ez = ux - ucx, uy - ucy, uz - ucz
    if ex != 0.0 or ey != 0.0 or ez != 0.0:  # outside the box (or NaN)
        outside = math.sqrt(ex * ex + ey * ey + ez * ez) * spacing
        d += outside
        # d(c(p)) + |p - c(p)|: along clamped axes c does not move, |p - c| does.
        if ex != 0.0:
            gx = np.float32(ex * spacing / outside)
        if ey != 0.0:
            gy = np.float32(ey * spacing / outside)
        if ez != 0.0:
            gz = np.float32(ez * spacing / outside)
    norm = np.sqrt(gx * gx + gy * gy + gz * gz)  # float32, in numpy's summation order
    if norm < _F32_TINY:  # NaN stays NaN, zero stays zero
        norm = _F32_TINY
    return d, np.float64(gx / norm), np.float64(gy / norm), np.float64(gz / norm)


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def nearest_node_value(
    values: npt.NDArray[np.float32],
    shape: tuple[int, int, int],
    geom: tuple[float, float, float, float, float],
    x: float,
    y: float,
    z: float,
) -> tuple[float, float]:
    """The value [m] of the grid node nearest the object-frame point (x, y, z) [m] (clamped
    to the box) and the point's distance outside the box [m] (0 inside): the parts of
    :meth:`SignedDistanceGrid.query_nearest`, whose value is their sum. NaN coordinates give
    NaN."""
    nx, ny, nz = shape
    inv_spacing, spacing, ox, oy, oz = geom
    ux = x * inv_spacing - ox
    uy = y * inv_spacing - oy
    uz = z * inv_spacing - oz
    if not (math.isfinite(ux) and math.isfinite(uy) and math.isfinite(uz)):
        return math.nan, math.nan
    cx = min(max(ux, 0.0), nx - 1.0)
    cy = min(max(uy, 0.0), ny - 1.0)
    cz = min(max(uz, 0.0), nz - 1.0)
    i = np.uint64(int(np.rint(cx)) * (ny * nz) + int(np.rint(cy)) * nz + int(np.rint(cz)))
    outside = math.sqrt((ux - cx) ** 2 + (uy - cy) ** 2 + (uz - cz) ** 2) * spacing
    return float(values[i]), outside


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def ball_may_reach(
    values: npt.NDArray[np.float32],
    shape: tuple[int, int, int],
    geom: tuple[float, float, float, float, float],
    centre: tuple[float, float, float],
    radius: float,
    threshold: float,
) -> bool:
    """:meth:`SignedDistanceGrid.near_spheres` for one ball (centre [m], radius [m]) and a
    threshold [m] the caller has checked lies in [0, the values on the box's faces): False only
    where no point of the ball has a nearest-node value below ``threshold``. NaN: True."""
    value, outside = nearest_node_value(values, shape, geom, centre[0], centre[1], centre[2])
    if not math.isfinite(value):
        return True
    half_diagonal = 0.5 * math.sqrt(3.0) * geom[1]
    lower = max(value - outside - 2.0 * half_diagonal, outside)  # the true distance is above
    return lower - radius - half_diagonal - 1e-6 < threshold
