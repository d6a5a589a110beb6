"""Signed distance field of an object on a regular grid (paper Sec. III-B).

The grid lives in the object's canonical frame. Node ``(i, j, k)`` sits at
``origin + spacing * (i, j, k)`` [m] and stores the signed distance to the object surface [m],
negative inside and positive outside, as float32.

Building a grid (``SignedDistanceGrid.from_mesh``) is :mod:`wholehand.models.sdf_build`'s job.

Querying is vectorised numpy with no Python loop over points: ``query`` (trilinear
interpolation), ``query_with_gradient`` (plus the unit gradient of the interpolant, i.e. the
outward surface normal near the surface) and ``query_nearest`` (nearest node, for culling).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import cast

import numba
import numpy as np
import numpy.typing as npt
import trimesh

from wholehand.errors import AssetError, ConfigError
from wholehand.jit import CACHE
from wholehand.models import cache
from wholehand.models.sdf_build import DEFAULT_EXACT_BAND, compute_grid_values
from wholehand.models.sdf_lookup import (
    ball_may_reach,
    grid_arguments,
    grid_tuples,
    nearest_node_value,
)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

log = logging.getLogger(__name__)

SDF_ALGORITHM = "sdf-grid-v2"
"""Name of the build algorithm; part of the cache key (bump it when the algorithm changes)."""

DEFAULT_SPACING: float = 0.002
"""Default grid spacing [m]."""

DEFAULT_PADDING: float = 0.03
"""Default margin between the mesh's bounding box and the grid boundary [m]."""

MAX_GRID_NODES: int = 64_000_000
"""Largest grid accepted by the builder (256 MB of float32); beyond, raise the spacing."""


@dataclass(frozen=True, eq=False)
class SignedDistanceGrid:
    """Signed distances [m] to an object's surface on a regular grid in the object frame.

    Negative inside, positive outside. Values are stored as float32 (half the memory and gather
    bandwidth of float64; 2 mm cells make the 6e-8 relative rounding irrelevant); queries take
    float64 or float32 points and return float64.

    Points outside the grid box get ``d(c) + |p - c|`` with ``c`` the point clamped to the box: an
    upper bound on the true distance that is continuous across the box boundary, and at least the
    boundary value (about ``padding`` [m] for a grid built with :meth:`from_mesh`), so such points
    are never contacts. NaN coordinates propagate: a point with a NaN coordinate gets a NaN
    distance and a NaN gradient (no error is raised on the control path; callers count them).
    """

    origin: FloatArray
    """(3,) position of node (0, 0, 0) in the object frame [m]."""
    spacing: float
    """Distance between neighbouring nodes along each axis [m]."""
    values: npt.NDArray[np.float32]
    """(nx, ny, nz) signed distance at each node [m], read-only, C order (x slowest)."""

    # Derived constants of the hot path, laid out for (3, P) arithmetic (see ``_locate``).
    _flat: npt.NDArray[np.float32] = field(init=False, repr=False)
    _origin_idx: FloatArray = field(init=False, repr=False)
    _upper: FloatArray = field(init=False, repr=False)
    _upper_cell: FloatArray = field(init=False, repr=False)
    _strides: FloatArray = field(init=False, repr=False)
    _corner_offsets: IntArray = field(init=False, repr=False)
    _boundary_min: float = field(init=False, repr=False)
    _lookup: tuple[npt.NDArray[np.float32], npt.NDArray[np.int64], FloatArray] = field(
        init=False, repr=False
    )

    def __post_init__(self) -> None:
        origin = np.array(self.origin, dtype=np.float64).reshape(-1)
        if origin.shape != (3,) or not np.all(np.isfinite(origin)):
            raise ConfigError(
                f"SignedDistanceGrid: origin must be 3 finite numbers, got {self.origin!r}"
            )
        spacing = float(self.spacing)
        if not (np.isfinite(spacing) and spacing > 0.0):
            raise ConfigError(f"SignedDistanceGrid: spacing must be > 0 [m], got {self.spacing!r}")
        values = np.ascontiguousarray(self.values, dtype=np.float32)
        if values.ndim != 3 or min(values.shape) < 2:
            raise ConfigError(
                f"SignedDistanceGrid: values must be a 3-D array with at least 2 nodes per axis, "
                f"got shape {np.shape(self.values)}"
            )
        if not np.all(np.isfinite(values)):
            raise ConfigError("SignedDistanceGrid: values contain NaN or inf")
        values.flags.writeable = False
        origin.flags.writeable = False
        nx, ny, nz = values.shape
        offsets = [dx * ny * nz + dy * nz + dz for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)]
        upper = np.array(values.shape, dtype=np.float64)[:, None] - 1.0
        set_ = object.__setattr__
        set_(self, "origin", origin)
        set_(self, "spacing", spacing)
        set_(self, "values", values)
        set_(self, "_flat", values.reshape(-1))
        set_(self, "_origin_idx", (origin / spacing)[:, None])
        set_(self, "_upper", upper)
        set_(self, "_upper_cell", upper - 1.0)
        set_(self, "_strides", np.array([ny * nz, nz, 1], dtype=np.float64))
        set_(self, "_corner_offsets", np.array(offsets, dtype=np.intp)[:, None])
        box_faces = (values[0], values[-1], values[:, 0], values[:, -1], values[..., 0])
        lowest = min(float(face.min()) for face in (*box_faces, values[..., -1]))
        set_(self, "_boundary_min", lowest)
        set_(self, "_lookup", grid_arguments(self))

    # --- geometry of the grid ------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int, int]:
        """(nx, ny, nz) number of nodes along each axis."""
        nx, ny, nz = self.values.shape
        return int(nx), int(ny), int(nz)

    @property
    def bounds(self) -> FloatArray:
        """(2, 3) lower and upper corner of the grid box in the object frame [m]."""
        return np.stack([self.origin, self.origin + self.spacing * self._upper[:, 0]])

    def node_positions(self, index: npt.ArrayLike | None = None) -> FloatArray:
        """(M, 3) object-frame positions [m] of the nodes with (M, 3) integer ``index``; all nodes
        in C order (x slowest) when ``index`` is None."""
        if index is None:
            axes = [np.arange(n, dtype=np.float64) for n in self.shape]
            index_f = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        else:
            index_f = np.asarray(index, dtype=np.float64).reshape(-1, 3)
        return self.origin + self.spacing * index_f

    # --- queries (control-loop hot path) -------------------------------------------------------
    # Layout: coordinates are handled as (3, P) arrays so that every numpy pass runs over P
    # contiguous elements (broadcasting against (3,) rows would run inner loops of length 3, about
    # twice slower); the 8 corner values are gathered as (8, P) float32 and interpolated in
    # float32 (fractions in [0, 1] with 6e-8 relative rounding: 1e-10 m on 2 mm cells).
    def _grid_coords(self, points_obj: npt.ArrayLike) -> FloatArray:
        """(3, P) continuous grid coordinates of (P, 3) object-frame points."""
        p = np.asarray(points_obj)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ConfigError(
                f"SignedDistanceGrid: points must have shape (P, 3) in the object frame [m], "
                f"got {p.shape}"
            )
        u = np.array(p.T, dtype=np.float64, order="C")
        u *= 1.0 / self.spacing
        u -= self._origin_idx
        return u

    def _locate(self, u: FloatArray) -> tuple[FloatArray, npt.NDArray[np.float32], IntArray]:
        """Clamped coordinates (3, P), fractions in the cell (3, P) float32 and the flat indices
        of the 8 cell corners (8, P). NaN coordinates give NaN fractions, never a bad index."""
        uc = np.maximum(u, 0.0)  # NaN stays NaN (np.clip is slower for small arrays)
        np.minimum(uc, self._upper, out=uc)
        cell = np.floor(uc)
        np.fmin(cell, self._upper_cell, out=cell)  # fmin(NaN, x) = x: a safe index
        base = (self._strides @ cell).astype(np.intp)
        frac = (uc - cell).astype(np.float32)
        return uc, frac, self._corner_offsets + base

    def _outside(self, u: FloatArray, uc: FloatArray) -> FloatArray | None:
        """(P,) distance [m] from each point to the grid box, or None if all are inside."""
        excess = uc - u
        if not excess.any():  # NaN counts as True: NaN propagates through the sum below
            return None
        return cast(FloatArray, np.sqrt(np.einsum("ij,ij->j", excess, excess)) * self.spacing)

    def query(self, points_obj: npt.ArrayLike) -> FloatArray:
        """(P,) signed distance [m] at (P, 3) object-frame points [m], trilinearly interpolated.

        Exact at the nodes; between them the interpolation error is about ``spacing^2 / (8 R)``
        on a surface of curvature radius R, at most ``sqrt(3)/2 * spacing`` at creases.
        """
        u = self._grid_coords(points_obj)
        uc, (tx, ty, tz), corners = self._locate(u)
        v = np.take(self._flat, corners)  # (8, P), corner (dx, dy, dz) at row 4 dx + 2 dy + dz
        a = v[0::2] + tz * (v[1::2] - v[0::2])  # (4, P): rows (x0y0, x0y1, x1y0, x1y1)
        b = a[0::2] + ty * (a[1::2] - a[0::2])  # (2, P): rows (x0, x1)
        dist = (b[0] + tx * (b[1] - b[0])).astype(np.float64)
        outside = self._outside(u, uc)
        if outside is not None:
            dist += outside
        return cast(FloatArray, dist)

    def query_with_gradient(self, points_obj: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Signed distance and its unit gradient at (P, 3) object-frame points [m].

        Returns:
            distances: (P,) signed distance [m], as :meth:`query`.
            gradients: (P, 3) unit gradient of the trilinear interpolant (object frame): the
                outward surface normal near the surface. Outside the grid box, the gradient of
                ``d(c) + |p - c|``. A zero vector where the gradient vanishes (only possible deep
                inside, on the medial axis).
        """
        u = self._grid_coords(points_obj)
        uc, (tx, ty, tz), corners = self._locate(u)
        v = np.take(self._flat, corners)
        ez = v[1::2] - v[0::2]  # (4, P) z-differences per (x, y) edge
        a = v[0::2] + tz * ez
        ey = a[1::2] - a[0::2]  # (2, P) y-differences per x
        b = a[0::2] + ty * ey
        ex = b[1] - b[0]
        dist = (b[0] + tx * ex).astype(np.float64)
        gz = ez[0::2] + ty * (ez[1::2] - ez[0::2])  # (2, P) per x
        grad = np.empty((3, len(tx)), dtype=np.float32)  # (3, P) until the end
        grad[0] = ex
        grad[1] = ey[0] + tx * (ey[1] - ey[0])
        grad[2] = gz[0] + tx * (gz[1] - gz[0])
        outside = self._outside(u, uc)
        if outside is not None:
            dist += outside
            # d(c(p)) + |p - c(p)|: along clamped axes c does not move, |p - c| does.
            excess = u - uc
            clamped = excess != 0.0  # True for NaN too: NaN propagates
            with np.errstate(invalid="ignore", divide="ignore"):
                grad[clamped] = (excess * self.spacing / outside)[clamped]
        norm = np.sqrt(np.einsum("ij,ij->j", grad, grad))
        grad /= np.maximum(norm, np.float32(1e-30))  # NaN stays NaN, zero stays zero
        return dist, np.ascontiguousarray(grad.T, dtype=np.float64)

    def query_nearest(self, points_obj: npt.ArrayLike) -> FloatArray:
        """(P,) value at the nearest node [m], plus the distance outside the grid box; no
        interpolation, about half the cost of :meth:`query`.

        Where node values are exact (within ``exact_band`` of the surface) it differs from the
        true distance by at most ``sqrt(3)/2 * spacing``, and from :meth:`query` by at most
        ``spacing``: ``query_nearest(p) < threshold + spacing`` is a safe cull before the exact
        lookup. NaN propagates as in :meth:`query`."""
        u = self._grid_coords(points_obj)
        uc = np.maximum(u, 0.0)
        np.minimum(uc, self._upper, out=uc)
        node = np.rint(uc)
        np.fmin(node, self._upper, out=node)
        dist = np.take(self._flat, (self._strides @ node).astype(np.intp)).astype(np.float64)
        outside = self._outside(u, uc)
        if outside is not None:
            dist += outside
        return dist

    def nearest_below(self, points_obj: npt.ArrayLike, threshold: float) -> IntArray:
        """Indices of the (P, 3) object-frame points [m] whose :meth:`query_nearest` value is
        below ``threshold`` [m], ascending: the same cull, one compiled pass with no temporary
        arrays (for the hundreds of thousands of points of a batch of grasp candidates). NaN
        points are never below."""
        p = np.ascontiguousarray(points_obj, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ConfigError(
                f"SignedDistanceGrid: points must have shape (P, 3) in the object frame [m], "
                f"got {p.shape}"
            )
        return cast(
            IntArray,
            _nearest_below(p, *self._lookup, float(threshold)),
        )

    def near_spheres(
        self, centres: npt.ArrayLike, radius: npt.ArrayLike, threshold: float
    ) -> npt.NDArray[np.bool_]:
        """(N,) whether the ball of ``radius`` (N,) [m] about each of the (N, 3) object-frame
        ``centres`` [m] may hold a point whose :meth:`query_nearest` value is below
        ``threshold`` [m] (>= 0): False only where none can, so that :meth:`nearest_below` need
        not look at the points of such a ball.

        The bound holds for a grid built by :meth:`from_mesh` (values exact near the surface,
        farther out too large in magnitude by less than ``sqrt(3)/2`` cells, signs exact, the
        mesh inside the box): the true distance at a centre is at least both its distance
        outside the box and its nearest node's value less ``sqrt(3)`` cells and that distance,
        and a point below the threshold lies within ``threshold + radius + sqrt(3)/2`` cells of
        the surface. Where the threshold is negative or reaches the values on the box's faces
        (a point outside the box could then be below it), every ball may."""
        c = np.ascontiguousarray(centres, dtype=np.float64).reshape(-1, 3)
        r = np.ascontiguousarray(np.broadcast_to(radius, c.shape[:1]), dtype=np.float64)
        if not self.culls_below(threshold):
            return np.ones(c.shape[0], dtype=np.bool_)
        return cast(
            npt.NDArray[np.bool_],
            _near_spheres(c, r, *self._lookup, float(threshold)),
        )

    def culls_below(self, threshold: float) -> bool:
        """Whether :meth:`near_spheres` may rule a ball out at ``threshold`` [m]: in [0, the
        values on the box's faces)."""
        return 0.0 <= threshold < self._boundary_min

    # --- persistence ---------------------------------------------------------------------------
    def to_arrays(self) -> dict[str, np.ndarray]:
        """The grid as plain arrays (for :mod:`wholehand.models.cache` or ``np.savez``)."""
        return {
            "origin": np.asarray(self.origin),
            "spacing": np.array(self.spacing),
            "values": np.asarray(self.values),
        }

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> SignedDistanceGrid:
        """Inverse of :meth:`to_arrays`."""
        return cls(
            origin=np.asarray(arrays["origin"], dtype=np.float64),
            spacing=float(arrays["spacing"]),
            values=np.asarray(arrays["values"], dtype=np.float32),
        )

    # --- building ------------------------------------------------------------------------------
    @classmethod
    def from_mesh(
        cls,
        mesh: trimesh.Trimesh,
        spacing: float = DEFAULT_SPACING,
        padding: float = DEFAULT_PADDING,
        *,
        exact_band: float = DEFAULT_EXACT_BAND,
        use_cache: bool = True,
    ) -> SignedDistanceGrid:
        """The SDF of a watertight mesh (object frame, metres) on a grid covering its bounding box
        plus ``padding`` [m] on every side, with node ``spacing`` [m].

        Node values are exact (to float32 rounding; see the module docstring for the candidate
        faces) within ``exact_band`` [m] of the surface and at most ``sqrt(3)/2 * spacing`` too
        large beyond; node signs are exact for a closed mesh (pseudo-normals in the band,
        connected components beyond).
        Cached on disk (:mod:`wholehand.models.cache`, kind ``"sdf"``) under a hash of the
        vertex and face bytes, the spacing, the padding, the band and the algorithm version.

        Raises:
            ConfigError: spacing or padding not positive, or a grid above ``MAX_GRID_NODES``.
            AssetError: the mesh is empty, not watertight, or wound inside out.
        """
        spacing, padding, exact_band = _checked_sizes(spacing, padding, exact_band)
        vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
        faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
        if len(faces) == 0:
            raise AssetError("SignedDistanceGrid.from_mesh: the mesh has no faces")
        origin, shape = grid_layout(vertices, spacing, padding)
        n_nodes = int(np.prod(shape))
        if n_nodes > MAX_GRID_NODES:
            raise ConfigError(
                f"SignedDistanceGrid.from_mesh: a {shape} grid ({n_nodes:,} nodes) at spacing "
                f"{spacing} m exceeds {MAX_GRID_NODES:,} nodes; raise the spacing or check the "
                "mesh units (metres expected)"
            )
        key = cache.content_hash(
            SDF_ALGORITHM, vertices.tobytes(), faces.tobytes(), spacing, padding, exact_band
        )
        if use_cache:
            hit = cache.load_arrays("sdf", key, ("origin", "spacing", "values"))
            if hit is not None:
                try:
                    return cls.from_arrays(hit)
                except (KeyError, ConfigError):
                    log.warning("ignoring a malformed SDF cache entry %s", key)
        if not (mesh.is_watertight and mesh.is_winding_consistent):
            raise AssetError(
                "SignedDistanceGrid.from_mesh: the mesh is not watertight (or its winding is "
                "inconsistent), so inside and outside are undefined; repair it first "
                "(ObjectModel.from_mesh(..., repair=True))"
            )
        if mesh.volume < 0.0:
            raise AssetError(
                "SignedDistanceGrid.from_mesh: the mesh is wound inside out (negative volume); "
                "call mesh.invert() or trimesh.repair.fix_normals(mesh) first"
            )
        t0 = time.perf_counter()
        values = compute_grid_values(vertices, faces, origin, spacing, shape, exact_band)
        log.info(
            "built a %s SDF grid (%d faces, %.1f mm spacing) in %.2f s",
            shape,
            len(faces),
            spacing * 1e3,
            time.perf_counter() - t0,
        )
        grid = cls(origin=origin, spacing=spacing, values=values)
        if use_cache:
            cache.save_arrays("sdf", key, grid.to_arrays())
        return grid


def grid_layout(
    vertices: FloatArray, spacing: float, padding: float
) -> tuple[FloatArray, tuple[int, int, int]]:
    """Origin [m] and node counts of a grid covering the vertices' box plus ``padding``, centred."""
    lo = vertices.min(axis=0) - padding
    hi = vertices.max(axis=0) + padding
    n = np.maximum(np.ceil((hi - lo) / spacing).astype(np.int64) + 1, 2)
    centre = 0.5 * (lo + hi)
    origin = centre - 0.5 * spacing * (n - 1)
    return origin, (int(n[0]), int(n[1]), int(n[2]))


# ----------------------------------------------------------------------------------------------
# Exact distances to a triangle mesh
# ----------------------------------------------------------------------------------------------


def _checked_sizes(spacing: float, padding: float, exact_band: float) -> tuple[float, float, float]:
    """The grid's spacing (> 0), padding and exact band (>= 0) [m] as floats."""
    spacing, padding, exact_band = float(spacing), float(padding), float(exact_band)
    if not (np.isfinite(spacing) and spacing > 0.0):
        raise ConfigError(f"SignedDistanceGrid.from_mesh: spacing must be > 0 [m], got {spacing!r}")
    if not (np.isfinite(padding) and padding >= 0.0):
        raise ConfigError(
            f"SignedDistanceGrid.from_mesh: padding must be >= 0 [m], got {padding!r}"
        )
    if not (np.isfinite(exact_band) and exact_band >= 0.0):
        raise ConfigError(
            f"SignedDistanceGrid.from_mesh: exact_band must be >= 0 [m], got {exact_band!r}"
        )
    return spacing, padding, exact_band


@numba.njit(cache=CACHE, nogil=True)
def _nearest_below(
    points: FloatArray,
    values: npt.NDArray[np.float32],
    dims: npt.NDArray[np.int64],
    geom: FloatArray,
    threshold: float,
) -> IntArray:  # pragma: no cover - jit
    """Indices of ``points`` (P, 3) whose nearest node's value, plus the distance outside the
    grid box, is below ``threshold`` (:meth:`SignedDistanceGrid.query_nearest`); the grid as
    :func:`~wholehand.models.sdf_lookup.grid_arguments` gives it."""
    shape, g = grid_tuples(dims, geom)
    out = np.empty(points.shape[0], dtype=np.intp)
    found = 0
    for i in range(points.shape[0]):
        value, outside = nearest_node_value(
            values, shape, g, points[i, 0], points[i, 1], points[i, 2]
        )
        if value + outside < threshold:  # NaN: never
            out[found] = i
            found += 1
    return out[:found]


@numba.njit(cache=CACHE, nogil=True)
def _near_spheres(
    centres: FloatArray,
    radius: FloatArray,
    values: npt.NDArray[np.float32],
    dims: npt.NDArray[np.int64],
    geom: FloatArray,
    threshold: float,
) -> npt.NDArray[np.bool_]:  # pragma: no cover - jit
    """:meth:`SignedDistanceGrid.near_spheres` for a threshold in [0, the box faces' values)."""
    shape, g = grid_tuples(dims, geom)
    out = np.empty(centres.shape[0], dtype=np.bool_)
    for i in range(centres.shape[0]):
        centre = (centres[i, 0], centres[i, 1], centres[i, 2])
        out[i] = ball_may_reach(values, shape, g, centre, radius[i], threshold)
    return out
