"""``wholehand bench thin-walls``: how well SDF grids represent thin plates and shells.

For each wall thickness, a tilted plate and a cylindrical shell (a tube, as a cup's wall) are
built at the default grid spacing and at ``sdf_spacing="auto"``. Points are placed near the
surface (up to a third of the wall inside, up to 2 mm outside) and the grid's sign and normal
(gradient) are compared with the exact signed distance to the mesh and the direction to its
closest point (:class:`~wholehand.models.sdf_build.MeshDistance`).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import trimesh

from wholehand.models.objects import AUTO_SPACING, ObjectModel
from wholehand.models.sdf import DEFAULT_SPACING
from wholehand.models.sdf_build import MeshDistance

WALLS_MM = (2.0, 3.0, 4.0, 5.0)
"""Wall thicknesses measured by default [mm]."""

NORMAL_TOLERANCE_DEG = 30.0
"""A grid normal further than this from the exact one counts as wrong."""

OUTSIDE_BAND = 0.002
"""Points are placed up to this far outside the surface [m]."""

_TILT = trimesh.transformations.rotation_matrix(0.5, [1.0, 1.0, 0.3])
"""Fixed tilt of every shape, so that no wall lies along the grid axes."""


def _shapes(wall: float) -> dict[str, trimesh.Trimesh]:
    plate = trimesh.creation.box(extents=(0.12, 0.08, wall))
    shell = trimesh.creation.annulus(r_min=0.04 - wall, r_max=0.04, height=0.09, sections=96)
    for mesh in (plate, shell):
        mesh.apply_transform(_TILT)
    return {"plate": plate, "shell": shell}


def grid_errors(obj: ObjectModel, wall: float, points: int, seed: int) -> dict[str, Any]:
    """Wrong signs and normals of ``obj``'s grid near its surface (see the module docstring)."""
    rng = np.random.default_rng(seed)
    mesh = obj.mesh
    surface, face = trimesh.sample.sample_surface(mesh, points, seed=seed)
    normal = np.asarray(mesh.face_normals)[face]
    depth = rng.uniform(-wall / 3.0, OUTSIDE_BAND, points)  # < 0: inside
    p = np.asarray(surface) + depth[:, None] * normal
    exact = MeshDistance(np.asarray(mesh.vertices), np.asarray(mesh.faces), obj.grid_spacing / 3)
    truth = exact.signed_distance(p, workers=1)
    away = p - truth.closest
    length = np.linalg.norm(away, axis=1)
    usable = length > 1e-5  # on the surface itself the direction is undefined
    n_true = np.sign(truth.distance)[:, None] * away / np.maximum(length, 1e-300)[:, None]
    d, gradient = obj.sdf.query_with_gradient(p)
    g_norm = np.linalg.norm(gradient, axis=1)
    cos = np.einsum("ij,ij->i", gradient, n_true) / np.maximum(g_norm, 1e-300)
    cos = np.where(g_norm > 1e-9, cos, 0.0)
    inside = truth.distance < 0.0
    out: dict[str, Any] = {}
    for band, rows in (("inside", inside & usable), ("outside", ~inside & usable)):
        wrong_sign = (d[rows] < 0.0) != inside[rows]
        out[band] = {
            "points": int(rows.sum()),
            "wrong_sign_pct": 100.0 * float(wrong_sign.mean()),
            "normal_off_pct": 100.0
            * float((cos[rows] < np.cos(np.radians(NORMAL_TOLERANCE_DEG))).mean()),
            "normal_flipped_pct": 100.0 * float((cos[rows] < 0.0).mean()),
        }
    return out


def run_thin_wall_benchmark(
    walls_mm: tuple[float, ...] = WALLS_MM, points: int = 4000, seed: int = 0
) -> dict[str, Any]:
    """Grid errors per shape and wall thickness, at the default spacing and at ``"auto"``."""
    rows = []
    for wall_mm in walls_mm:
        wall = wall_mm * 1e-3
        for shape, mesh in _shapes(wall).items():
            for spacing in (DEFAULT_SPACING, AUTO_SPACING):
                name = f"{shape}-{wall_mm:g}mm"
                obj = ObjectModel.from_trimesh(mesh, name, sdf_spacing=spacing)
                start = time.perf_counter()
                grid = obj.sdf
                grid_s = time.perf_counter() - start  # build, or load from the cache
                rows.append(
                    {
                        "shape": shape,
                        "wall_mm": wall_mm,
                        "sdf_spacing": spacing,
                        "thinnest_wall_mm": 1e3 * obj.thinnest_wall,
                        "grid_spacing_mm": 1e3 * obj.grid_spacing,
                        "grid_nodes": int(np.prod(grid.shape)),
                        "grid_s": grid_s,
                        **grid_errors(obj, wall, points, seed),
                    }
                )
    return {
        "normal_tolerance_deg": NORMAL_TOLERANCE_DEG,
        "inside_depth": "up to a third of the wall",
        "outside_band_m": OUTSIDE_BAND,
        "rows": rows,
    }
