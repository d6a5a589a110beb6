"""Link surface meshes and the candidate contact points sampled on them (paper Sec. III-B).

Each link surface gets ``UNIFORM_SAMPLES_PER_LINK`` points drawn uniformly by area, reduced by
farthest-point sampling to ``SAMPLE_DENSITY_PER_CM2`` points per cm^2 (at least one).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, cast

import coal
import numpy as np
import numpy.typing as npt
import pinocchio as pin
import trimesh

from wholehand.errors import AssetError

FloatArray = npt.NDArray[np.float64]

SPHERE_SUBDIVISIONS = 3
"""Icosphere subdivisions used to mesh sphere primitives (max. chord error < 1% of r)."""
CYLINDER_SECTIONS = 64
"""Facets around cylinder and capsule primitives."""


def geometry_to_trimesh(obj: pin.GeometryObject) -> trimesh.Trimesh:
    """Mesh of one Pinocchio geometry object in its own frame [m]."""
    geom = obj.geometry
    primitive: Any = None  # trimesh.creation is untyped
    if isinstance(geom, coal.Box):
        primitive = trimesh.creation.box(extents=2.0 * np.asarray(geom.halfSide))
    elif isinstance(geom, coal.Sphere):
        primitive = trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIVISIONS, radius=geom.radius)
    elif isinstance(geom, coal.Cylinder):
        primitive = trimesh.creation.cylinder(
            radius=geom.radius, height=2.0 * geom.halfLength, sections=CYLINDER_SECTIONS
        )
    elif isinstance(geom, coal.Capsule):
        primitive = trimesh.creation.capsule(
            height=2.0 * geom.halfLength, radius=geom.radius, count=[CYLINDER_SECTIONS, 16]
        )
    if primitive is not None:
        return cast(trimesh.Trimesh, primitive)
    mesh_path = Path(obj.meshPath) if obj.meshPath else None
    if mesh_path is not None and mesh_path.is_file():
        try:
            mesh = cast(trimesh.Trimesh, trimesh.load(mesh_path, force="mesh", process=True))
        except Exception as err:
            raise AssetError(
                f"cannot read mesh {mesh_path} of geometry {obj.name!r}: {err}"
            ) from err
        mesh.apply_scale(np.asarray(obj.meshScale, dtype=float))
        return mesh
    raise AssetError(
        f"geometry {obj.name!r} has an unsupported shape {type(geom).__name__} and no mesh file; "
        "use a box, sphere, cylinder, capsule or mesh in the URDF"
    )


def link_mesh_in_joint_frame(objects: list[pin.GeometryObject]) -> trimesh.Trimesh:
    """All geometry of one link as one mesh, in the frame of the link's parent joint [m]."""
    parts = []
    for obj in objects:
        mesh = geometry_to_trimesh(obj)
        mesh.apply_transform(obj.placement.homogeneous)  # placement: pose in the parent joint
        parts.append(mesh)
    return cast(trimesh.Trimesh, trimesh.util.concatenate(parts)) if len(parts) > 1 else parts[0]


def farthest_point_sampling(points: FloatArray, count: int, start: int = 0) -> npt.NDArray[np.intp]:
    """Indices of ``count`` points picked greedily, each farthest from those already picked."""
    count = min(count, len(points))
    chosen = np.empty(count, dtype=np.intp)
    chosen[0] = start
    d2 = np.sum((points - points[start]) ** 2, axis=1)
    for i in range(1, count):
        chosen[i] = int(np.argmax(d2))
        np.minimum(d2, np.sum((points - points[chosen[i]]) ** 2, axis=1), out=d2)
    return chosen


def sample_link_surface(
    mesh: trimesh.Trimesh, n_uniform: int, density_per_cm2: float, seed: int
) -> tuple[FloatArray, FloatArray]:
    """Candidate points and outward surface normals on a link mesh, in the mesh frame.

    Returns:
        points (M, 3) [m] and normals (M, 3), M = max(1, round(density * area[cm^2])),
        at most ``n_uniform``.
    """
    rng = np.random.default_rng(seed)
    uniform, faces = trimesh.sample.sample_surface(mesh, n_uniform, seed=rng)
    area_cm2 = float(mesh.area) * 1e4
    count = max(1, int(round(density_per_cm2 * area_cm2)))
    keep = farthest_point_sampling(np.asarray(uniform), count)
    return np.asarray(uniform)[keep], np.asarray(mesh.face_normals)[faces[keep]]
