"""Reading an object mesh, checking it (watertight, plausible size and face count) and repairing
what can be repaired (``repair=True``)."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import cast

import numpy as np
import numpy.typing as npt
import trimesh

from wholehand.errors import AssetError, ConfigError

log = logging.getLogger(__name__)

REPAIR_VOXEL_PITCH: float = 0.001
"""Voxel size of the last-resort remesh of ``repair=True`` [m] (raised for large objects so that
the voxel grid stays below 400 cells per axis)."""
REPAIR_MAX_CHANGE: float = 10.0
"""Largest change of the enclosed volume the voxel remesh may make [%], against the cleaned,
hole-filled surface (the YCB meshes registered for repair need no remesh and change by less
than 0.01 %); an open sheet would become a slab of made-up volume."""

MIN_EXTENT: float = 0.005
"""Smallest plausible largest extent of an object [m]; below, the mesh is probably in metres
scaled twice or in the wrong unit."""

MAX_EXTENT: float = 2.0
"""Largest plausible largest extent of a graspable object [m]; above, probably millimetres."""

MAX_MESH_FACES: int = 200_000
"""Largest object mesh accepted [triangles]. A grasped object needs no more (the YCB scans have
at most 16 k after repair); a 500 k-face scan took minutes and gigabytes in the convex
decomposition and the SDF. A larger mesh is refused with the fix (decimate it first)."""


def read_mesh(path: Path) -> trimesh.Trimesh:
    """The triangles of a mesh file as one mesh (vertices merged), or AssetError."""
    if not path.is_file():
        raise AssetError(
            f"mesh file {str(path)!r} does not exist; give the path to an STL/OBJ/PLY file "
            "or a YCB name (wholehand.models.object_catalogue.available_objects())"
        )
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as err:  # trimesh raises many types for unreadable files
        raise AssetError(f"cannot read mesh file {str(path)!r}: {err}") from err
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise AssetError(f"mesh file {str(path)!r} contains no triangles")
    if len(mesh.faces) > MAX_MESH_FACES:
        raise AssetError(
            f"mesh file {str(path)!r} has {len(mesh.faces)} triangles, more than the "
            f"{MAX_MESH_FACES} an object mesh may have (its convex decomposition and SDF would "
            "take minutes and gigabytes); decimate it first, e.g. with trimesh: "
            "mesh.simplify_quadric_decimation(face_count=50000) (pip install fast-simplification)"
        )
    # Checked before processing, which would silently drop such vertices and leave holes.
    bad = np.flatnonzero(~np.isfinite(np.asarray(mesh.vertices)).all(axis=1))
    if bad.size:
        raise AssetError(
            f"mesh file {str(path)!r} has {bad.size} vertices with NaN or infinite coordinates "
            f"(the first at index {int(bad[0])}); fix or re-export the mesh"
        )
    mesh.process()  # as trimesh.load(process=True): merge duplicate vertices
    return mesh


def describe_defects(mesh: trimesh.Trimesh) -> str:
    """Why a mesh is not watertight: boundary and non-manifold edge counts, winding, degenerate
    faces."""
    counts = np.bincount(mesh.edges_unique_inverse, minlength=len(mesh.edges_unique))
    boundary = int(np.sum(counts == 1))
    non_manifold = int(np.sum(counts > 2))
    degenerate = int(np.sum(~mesh.nondegenerate_faces(height=1e-12)))
    winding = "consistent" if mesh.is_winding_consistent else "inconsistent"
    return (
        f"{boundary} boundary edges (holes), {non_manifold} edges shared by more than two faces, "
        f"{degenerate} degenerate faces, winding {winding}"
    )


def repair_mesh(mesh: trimesh.Trimesh, name: str = "mesh") -> tuple[trimesh.Trimesh, str]:
    """A watertight copy of ``mesh`` and a note of what was done.

    Steps: merge duplicate vertices; drop degenerate faces (repeated vertex or zero area); drop
    faces that come in coincident pairs of opposite orientation and keep one of coincident
    duplicates (the defects of the YCB scans); drop unreferenced vertices; fill simple holes and
    make the winding consistent (trimesh). If still not watertight: remesh the filled voxelisation
    at ``REPAIR_VOXEL_PITCH`` by marching cubes (scikit-image), which changes the surface by up to
    a voxel and closes thin openings; the note reports the volume change.

    Raises:
        AssetError: nothing watertight could be made, or only by a voxel remesh that changes the
            enclosed volume by more than :data:`REPAIR_MAX_CHANGE` (an open sheet becomes a
            slab).
    """
    t0 = time.perf_counter()
    before = describe_defects(mesh)
    volume_before = float(mesh.volume)
    out = mesh.copy()
    out.merge_vertices()
    faces = np.asarray(out.faces)
    n_faces = len(faces)
    keep = out.nondegenerate_faces(height=1e-12)
    keep &= (
        (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])
    )
    n_degenerate = int(np.sum(~keep))
    keep, n_paired = _drop_coincident_faces(faces, keep)
    out.update_faces(keep)
    out.remove_unreferenced_vertices()
    trimesh.repair.fill_holes(out)
    trimesh.repair.fix_normals(out)
    steps = (
        f"removed {n_degenerate} degenerate and {n_paired} coincident faces of {n_faces}, filled "
        "holes, fixed winding"
    )
    if not (out.is_watertight and out.is_winding_consistent):
        filled = abs(float(out.volume)) if len(out.faces) else 0.0
        out = _voxel_remesh(out if len(out.faces) else mesh)
        _check_remesh_volume(name, filled, abs(float(out.volume)))
        pitch_mm = _voxel_pitch(mesh) * 1e3
        steps += f"; still open: remeshed by marching cubes of its filled {pitch_mm:.1f} mm voxels"
        if not out.is_watertight:
            raise AssetError(
                f"mesh of {name!r} could not be repaired ({describe_defects(out)}); repair it "
                "offline (e.g. MeshLab, Blender 3D-Print Toolbox)"
            )
    if out.volume < 0.0:
        out.invert()
    volume_after = float(out.volume)
    change = (
        100.0 * (volume_after - volume_before) / abs(volume_before)
        if volume_before
        else float("inf")
    )
    note = (
        f"repaired ({before}): {steps}; volume (of the surface as given, ill-defined if it had "
        f"holes) {volume_before * 1e6:.3f} -> "
        f"{volume_after * 1e6:.3f} cm^3 ({change:+.2f} %), {time.perf_counter() - t0:.2f} s"
    )
    if abs(change) > 5.0:
        log.warning("repair of %s changed its volume by %+.1f %%: %s", name, change, note)
    return out, note


def _drop_coincident_faces(
    faces: npt.NDArray[np.integer], keep: npt.NDArray[np.bool_]
) -> tuple[npt.NDArray[np.bool_], int]:
    """Face mask without coincident faces: on the same three vertices, opposite orientations
    cancel in pairs and at most one face of the surviving orientation remains."""
    keep = keep.copy()
    ordered = np.sort(faces, axis=1)
    _, group, counts = np.unique(ordered, axis=0, return_inverse=True, return_counts=True)
    group = group.reshape(-1)
    shared = np.flatnonzero((counts[group] > 1) & keep)
    if shared.size == 0:
        return keep, 0
    # +1 if the face is an even permutation of its sorted vertices (same orientation), else -1.
    first = np.argmin(faces[shared], axis=1)
    following = faces[shared, (first + 1) % 3]
    orientation = np.where(following == ordered[shared, 1], 1, -1)
    removed = 0
    for g in np.unique(group[shared]):
        members = shared[group[shared] == g]
        signs = orientation[group[shared] == g]
        keep[members] = False
        balance = int(signs.sum())
        if balance != 0:
            keep[members[signs == np.sign(balance)][0]] = True
        removed += len(members) - (balance != 0)
    return keep, removed


def _check_remesh_volume(name: str, filled: float, remeshed: float) -> None:
    """Refuse a voxel remesh that changes the volume of the cleaned, hole-filled surface by more
    than :data:`REPAIR_MAX_CHANGE`: the surface was no solid's (a sheet, a single-layer shell),
    and the remesh would give it walls a voxel thick."""
    change = 100.0 * (remeshed - filled) / filled if filled > 0.0 else float("inf")
    if not abs(change) <= REPAIR_MAX_CHANGE:
        raise AssetError(
            f"mesh of {name!r} cannot be closed without changing its volume: the cleaned, "
            f"hole-filled surface encloses {filled * 1e6:.3f} cm^3, its voxel remesh "
            f"{remeshed * 1e6:.3f} cm^3 ({change:+.1f} %, more than the {REPAIR_MAX_CHANGE:g} % a "
            "repair may change); an open surface (a sheet, a shell without a back) is not a "
            "solid: close it offline (e.g. MeshLab, Blender 3D-Print Toolbox)"
        )


def _voxel_pitch(mesh: trimesh.Trimesh) -> float:
    return max(REPAIR_VOXEL_PITCH, float(np.max(mesh.extents)) / 400.0)


def _voxel_remesh(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Watertight marching-cubes surface of the filled voxelisation of ``mesh``."""
    try:
        voxels = mesh.voxelized(pitch=_voxel_pitch(mesh)).fill()
        out = voxels.marching_cubes.copy()  # in voxel index units
        out.apply_transform(voxels.transform)
    except Exception as err:  # scikit-image missing or a voxelisation failure
        raise AssetError(f"voxel remesh failed: {err}; repair the mesh offline") from err
    out.merge_vertices()
    trimesh.repair.fix_normals(out)
    return cast(trimesh.Trimesh, out)


def check_extent(mesh: trimesh.Trimesh, name: str) -> None:
    largest = float(np.max(mesh.extents))
    if not np.isfinite(largest):
        raise AssetError(f"mesh of {name!r} has non-finite vertex coordinates")
    if largest > MAX_EXTENT:
        raise ConfigError(
            f"object {name!r} is {largest:.4g} m across (> {MAX_EXTENT} m): the mesh is probably "
            "in millimetres; scale it by 0.001 (meshes must be in metres)"
        )
    if largest < MIN_EXTENT:
        raise ConfigError(
            f"object {name!r} is only {largest:.3g} m across (< {MIN_EXTENT} m): a unit mix-up? "
            "meshes must be in metres"
        )
