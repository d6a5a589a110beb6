"""Wall thickness of a closed mesh, and the SDF grid spacing that resolves it.

A grid of spacing h cannot represent a wall thinner than a few h: trilinear interpolation across
the wall blends the distances of both faces, so points inside read the wrong sign and normals
come out tilted, zero or flipped (paper Sec. VI names thin objects as a limitation). The wall
thickness at a surface point is the length of the ray cast from it straight into the solid
until it leaves again (trimesh ray casting, rtree-accelerated); an object's *thinnest wall* is a
low quantile of that over area-uniform surface samples, so a few noisy triangles do not decide it.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import trimesh

FloatArray = npt.NDArray[np.float64]

WALL_SAMPLES: int = 2000
"""Surface samples whose inward rays measure the wall thickness."""

THIN_FRACTION: float = 0.02
"""The thinnest wall is the thickness that this fraction of the surface is thinner than."""

CELLS_PER_WALL: float = 3.0
"""Grid cells across the thinnest wall that :func:`spacing_for_wall` asks for. Measured on
tilted plates of 2-5 mm (``wholehand bench thin-walls``): at 3 cells, points up to a third of
the wall deep get the right sign and a normal within 30 deg of the true one."""

MIN_AUTO_SPACING: float = 0.0005
"""Finest spacing :func:`spacing_for_wall` picks [m]: below it, grids of a hand-sized object
pass tens of millions of nodes and take minutes to build."""

_RAY_OFFSET: float = 1e-5
"""Rays start this far inside the surface [m] so that they do not hit their own face."""


def wall_thickness(
    mesh: trimesh.Trimesh, samples: int = WALL_SAMPLES, seed: int = 0
) -> tuple[FloatArray, FloatArray]:
    """Wall thickness at area-uniform surface samples of a closed mesh.

    Args:
        mesh: watertight mesh, faces wound outward [m].
        samples: number of surface samples.
        seed: seed of the sampling.

    Returns:
        ``(points, thickness)``: (S, 3) sample points [m], mesh frame, and (S,) the distance
        from each along its inward face normal to where the ray leaves the solid [m] (inf if it
        never does, which a closed mesh rules out).
    """
    points, face = trimesh.sample.sample_surface(mesh, int(samples), seed=seed)
    points = np.asarray(points, dtype=np.float64)
    inward = -np.asarray(mesh.face_normals, dtype=np.float64)[face]
    origins = points + _RAY_OFFSET * inward
    hits, ray, _ = mesh.ray.intersects_location(origins, inward, multiple_hits=True)
    depth = np.einsum("ij,ij->i", hits - origins[ray], inward[ray])
    ahead = depth > 1e-9
    thickness = np.full(len(points), np.inf)
    np.minimum.at(thickness, ray[ahead], depth[ahead] + _RAY_OFFSET)
    return points, thickness


def thinnest_wall(
    mesh: trimesh.Trimesh, fraction: float = THIN_FRACTION, samples: int = WALL_SAMPLES
) -> float:
    """The wall thickness [m] that ``fraction`` of the surface is thinner than (seeded)."""
    _, thickness = wall_thickness(mesh, samples)
    return float(np.quantile(thickness, fraction))


def spacing_for_wall(wall: float, default: float) -> float:
    """Grid spacing [m] that puts ``CELLS_PER_WALL`` cells across a wall of ``wall`` [m]:
    never coarser than ``default`` [m], never finer than ``MIN_AUTO_SPACING``."""
    return float(np.clip(wall / CELLS_PER_WALL, min(MIN_AUTO_SPACING, default), default))
