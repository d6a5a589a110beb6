"""Primitive solids of uniform density: their meshes, volumes and analytic inertias, and how an
object's mass is chosen (:class:`~wholehand.models.objects.ObjectModel` builds its primitives
from these).

Every solid is centred at the origin; a cylinder's and a capsule's axis is z.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import trimesh

from wholehand.errors import ConfigError

FloatArray = npt.NDArray[np.float64]

DEFAULT_DENSITY: float = 500.0
"""Density given to objects without a registered or given mass [kg/m^3] (a generic value
between hollow plastic and solid wood; the resulting mass is an estimate, said so in
``ObjectModel.source``)."""

SPHERE_SUBDIVISIONS: int = 4
"""Icosphere subdivisions of sphere meshes (5120 faces; chord error 1.2e-3 R, 0.05 mm at 4 cm)."""

CYLINDER_SECTIONS: int = 128
"""Facets around cylinder and capsule meshes (chord error 3e-4 R)."""

CAPSULE_RINGS: int = 64
"""Latitude rings of each capsule hemisphere mesh."""


@dataclass(frozen=True)
class Solid:
    """A primitive solid of uniform density."""

    kind: str
    """``box``, ``sphere``, ``cylinder`` or ``capsule``."""
    dimensions: dict[str, Any]
    """Its dimensions [m] (see ``ObjectModel.dimensions``)."""
    mesh: trimesh.Trimesh
    """Its surface [m]."""
    volume: float
    """[m^3]"""
    inertia: Callable[[float], FloatArray]
    """Mass [kg] -> (3, 3) inertia about the centre (the origin) [kg*m^2]."""
    spec: str
    """Its primitive spec, e.g. ``"box:0.05x0.05x0.05"`` (the default object name)."""


def box(size: npt.ArrayLike) -> Solid:
    """A box of full side lengths ``size`` = (x, y, z) [m]."""
    dims = positive_vector(size, 3, "box size")
    x2, y2, z2 = dims**2
    size_t = (float(dims[0]), float(dims[1]), float(dims[2]))
    return Solid(
        "box",
        {"size": size_t},
        trimesh.creation.box(extents=dims),
        float(np.prod(dims)),
        lambda m: m / 12.0 * np.diag([y2 + z2, x2 + z2, x2 + y2]),
        "box:{}x{}x{}".format(*_fmt(size_t)),
    )


def sphere(radius: float) -> Solid:
    """A sphere of ``radius`` [m] (icosphere mesh, ``SPHERE_SUBDIVISIONS``)."""
    (r,) = positive_vector([radius], 1, "sphere radius")
    return Solid(
        "sphere",
        {"radius": float(r)},
        trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIVISIONS, radius=r),
        4.0 / 3.0 * np.pi * r**3,
        lambda m: 0.4 * m * r**2 * np.eye(3),
        f"sphere:{_fmt([r])[0]}",
    )


def cylinder(radius: float, height: float) -> Solid:
    """A solid cylinder of ``radius`` and ``height`` [m] (``CYLINDER_SECTIONS`` facets)."""
    r, h = positive_vector([radius, height], 2, "cylinder radius and height")

    def inertia(m: float) -> FloatArray:
        i_xx = m * (3.0 * r**2 + h**2) / 12.0
        return np.diag([i_xx, i_xx, 0.5 * m * r**2])

    return Solid(
        "cylinder",
        {"radius": float(r), "height": float(h)},
        trimesh.creation.cylinder(radius=r, height=h, sections=CYLINDER_SECTIONS),
        np.pi * r**2 * h,
        inertia,
        "cylinder:{}x{}".format(*_fmt([r, h])),
    )


def capsule(radius: float, length: float) -> Solid:
    """A cylinder of ``radius`` and ``length`` [m] (the distance between the hemisphere centres,
    as coal and MuJoCo define it; total length ``length + 2 radius``) capped by two
    hemispheres."""
    r, length = positive_vector([radius, length], 2, "capsule radius and length")
    v_cyl = np.pi * r**2 * length
    v_sph = 4.0 / 3.0 * np.pi * r**3

    def inertia(m: float) -> FloatArray:
        m_cyl, m_sph = m * v_cyl / (v_cyl + v_sph), m * v_sph / (v_cyl + v_sph)
        # Hemispheres: centroid 3r/8 from the flat face, parallel axis to the origin.
        i_xx = m_cyl * (3.0 * r**2 + length**2) / 12.0 + m_sph * (
            0.4 * r**2 + length**2 / 4.0 + 3.0 * length * r / 8.0
        )
        return np.diag([i_xx, i_xx, 0.5 * m_cyl * r**2 + 0.4 * m_sph * r**2])

    return Solid(
        "capsule",
        {"radius": float(r), "length": float(length)},
        trimesh.creation.capsule(height=length, radius=r, count=[CYLINDER_SECTIONS, CAPSULE_RINGS]),
        v_cyl + v_sph,
        inertia,
        "capsule:{}x{}".format(*_fmt([r, length])),
    )


def resolve_mass(
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


def positive_vector(values: npt.ArrayLike, n: int, what: str) -> FloatArray:
    """``values`` as ``n`` finite numbers > 0 [m]; else :class:`ConfigError` naming ``what``."""
    try:
        arr = np.asarray(values, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{what} must be {n} numbers [m], got {values!r}") from err
    if arr.shape != (n,) or not np.all(np.isfinite(arr)) or np.any(arr <= 0.0):
        raise ConfigError(f"{what} must be {n} finite numbers > 0 [m], got {values!r}")
    return arr


def _fmt(values: Any) -> list[str]:
    return [f"{float(v):g}" for v in values]
