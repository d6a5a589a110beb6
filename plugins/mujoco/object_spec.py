"""The object in a MuJoCo scene: its body, mass properties and collision geoms.

The body frame is the object frame of :class:`~wholehand.models.objects.ObjectModel` (the
canonical mesh frame); mass, centre of mass and inertia are set explicitly, never inferred from
the geoms. Primitives collide as MuJoCo primitives of exact size, meshes as the convex parts of a
CoACD decomposition (:mod:`wholehand.models.convex`), because MuJoCo collides a single mesh
geom as its convex hull and fills cavities (``collision="hull"`` keeps that behaviour for
comparison).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np
import numpy.typing as npt

from wholehand.errors import ConfigError

from .poses import set_spec_pose
from .scene_options import (
    HAND_BIT,
    OBJECT_BIT,
    OBJECT_BODY,
    OBJECT_JOINT,
    SceneOptions,
)

if TYPE_CHECKING:
    from wholehand.models.objects import ObjectModel

FloatArray = npt.NDArray[np.float64]


def _principal_inertia(obj: ObjectModel) -> tuple[FloatArray, FloatArray]:
    """Principal moments (3,) [kg*m^2] and the (4,) quaternion of the principal axes."""
    inertia = np.asarray(obj.inertia, dtype=float)
    if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
        raise ConfigError(f"object {obj.name!r}: inertia must be a finite (3, 3) matrix")
    moments, axes = np.linalg.eigh(0.5 * (inertia + inertia.T))
    if moments.min() <= 0:
        raise ConfigError(
            f"object {obj.name!r}: inertia about the centre of mass is not positive definite "
            f"(principal moments {moments.tolist()}); fix the object's mass properties"
        )
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1.0
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(axes).ravel())
    return moments, quat


def add_object_geoms(
    spec: mujoco.MjSpec, body: Any, obj: ObjectModel, opts: SceneOptions, mu: float
) -> int:
    """Add the collision geoms of the object to ``body``; return the number of convex parts
    (0: a primitive). Geoms are named ``object_geom`` or ``object_part_<i>``."""
    common = {
        "contype": OBJECT_BIT,
        "conaffinity": HAND_BIT,
        "condim": opts.condim,
        "friction": [mu, 0.005, 0.0001],
        "solref": list(opts.solref),
        "solimp": list(opts.solimp),
        "priority": 1,
        "rgba": [0.85, 0.55, 0.2, 1.0],
    }
    dims = obj.dimensions
    G = mujoco.mjtGeom
    primitives = {  # MuJoCo sizes: radius, half-lengths
        "box": (G.mjGEOM_BOX, lambda: (0.5 * np.asarray(dims["size"], dtype=float)).tolist()),
        "sphere": (G.mjGEOM_SPHERE, lambda: [float(dims["radius"]), 0.0, 0.0]),
        "cylinder": (
            G.mjGEOM_CYLINDER,
            lambda: [float(dims["radius"]), 0.5 * float(dims["height"]), 0.0],
        ),
        "capsule": (
            G.mjGEOM_CAPSULE,
            lambda: [float(dims["radius"]), 0.5 * float(dims["length"]), 0.0],
        ),
    }
    if obj.kind in primitives:
        geom_type, size = primitives[obj.kind]
        try:
            body.add_geom(name="object_geom", type=geom_type, size=size(), **common)
        except KeyError as err:
            raise ConfigError(
                f"object {obj.name!r} of kind {obj.kind!r} lacks dimension {err} "
                f"(has {sorted(dims)})"
            ) from err
        return 0
    if obj.kind != "mesh":
        raise ConfigError(
            f"object {obj.name!r} has kind {obj.kind!r}; expected mesh, box, sphere, cylinder or "
            "capsule"
        )
    if opts.collision == "hull":
        hull = obj.mesh.convex_hull
        parts = [(np.asarray(hull.vertices), np.asarray(hull.faces))]
    else:
        from wholehand.models.convex import convex_decomposition

        parts = convex_decomposition(obj.mesh, name=obj.name, **opts.coacd).parts()
    for i, (vertices, faces) in enumerate(parts):
        mesh = spec.add_mesh(name=f"object_part_{i}")
        mesh.uservert = np.asarray(vertices, dtype=np.float32).ravel().tolist()
        mesh.userface = np.asarray(faces, dtype=np.int32).ravel().tolist()
        mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
        body.add_geom(name=f"object_part_{i}", type=G.mjGEOM_MESH, meshname=mesh.name, **common)
    return len(parts)


def _add_visual_mesh(spec: mujoco.MjSpec, body: Any, obj: ObjectModel) -> None:
    mesh = spec.add_mesh(name="object_visual")
    mesh.uservert = np.asarray(obj.mesh.vertices, dtype=np.float32).ravel().tolist()
    mesh.userface = np.asarray(obj.mesh.faces, dtype=np.int32).ravel().tolist()
    mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
    body.add_geom(
        name="object_visual",
        type=mujoco.mjtGeom.mjGEOM_MESH,
        meshname="object_visual",
        contype=0,
        conaffinity=0,
        group=2,
        density=0,
        rgba=[0.85, 0.55, 0.2, 0.5],
    )


def add_object(
    spec: mujoco.MjSpec, obj: ObjectModel, wMo: FloatArray, opts: SceneOptions, mu: float
) -> int:
    """Add the object as body ``object`` with a free joint at ``wMo`` (4, 4), its mass
    properties set explicitly, its collision geoms and (``opts.visual_mesh``) its visual mesh;
    return the number of convex parts it collides as (0: a primitive)."""
    mass = float(obj.mass)
    if not (math.isfinite(mass) and mass > 0):
        raise ConfigError(f"object {obj.name!r}: mass must be a positive number [kg], got {mass!r}")
    com = np.asarray(obj.com, dtype=float)
    if com.shape != (3,) or not np.all(np.isfinite(com)):
        raise ConfigError(f"object {obj.name!r}: com must be a finite (3,) point, got {com!r}")
    moments, iquat = _principal_inertia(obj)
    body = spec.worldbody.add_body(name=OBJECT_BODY)
    set_spec_pose(body, wMo)
    body.add_freejoint(name=OBJECT_JOINT)
    body.explicitinertial = True
    body.mass = mass
    body.ipos = com.tolist()
    body.iquat = iquat.tolist()
    body.inertia = moments.tolist()
    parts = add_object_geoms(spec, body, obj, opts, mu)
    if opts.visual_mesh:
        _add_visual_mesh(spec, body, obj)
    return parts
