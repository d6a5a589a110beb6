"""How an object rests on a horizontal plane: its stable faces and the pose that puts it there.

A resting pose is named by the object-frame direction that points up (``up``, unit (3,)): the
object's orientation is any rotation taking ``up`` to world +z, turned about z by a yaw. The
stable directions come from trimesh's ``compute_stable_poses`` (the faces of the convex hull
on which the centre of mass projects inside, with the probability of landing on each from a
random drop), evaluated at the object's centre of mass without noise, so they are deterministic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import trimesh

from wholehand.errors import ConfigError
from wholehand.models.objects import ObjectModel

FloatArray = npt.NDArray[np.float64]

MIN_PROBABILITY = 0.02
"""Resting faces less likely than this (from a random drop) are left out [-]."""
ROUND_FACES = 8
"""A round object (a ball: hundreds of hull faces, none as likely as :data:`MIN_PROBABILITY`)
rests on its this-many likeliest faces."""


@dataclass(frozen=True)
class RestingFace:
    """A stable way for an object to rest on a horizontal plane."""

    up: FloatArray
    """(3,) unit vector, object frame, that points up (world +z) when the object rests."""
    probability: float
    """Chance of landing this way from a random drop [-]."""


def resting_faces(obj: ObjectModel, min_probability: float = MIN_PROBABILITY) -> list[RestingFace]:
    """The object's stable resting faces, most probable first (at least one): those at least
    ``min_probability`` likely, or for a round object, whose many faces are each less likely,
    its :data:`ROUND_FACES` likeliest."""
    transforms, probabilities = trimesh.poses.compute_stable_poses(
        obj.mesh, center_mass=np.asarray(obj.com, dtype=float), sigma=0.0, n_samples=1
    )
    ranked = sorted(
        (
            RestingFace(np.asarray(T[2, :3], dtype=float), float(p))
            for T, p in zip(transforms, probabilities, strict=True)
        ),
        key=lambda face: -face.probability,
    )
    faces = [face for face in ranked if face.probability >= min_probability]
    if not faces:
        faces = [face for face in ranked[:ROUND_FACES] if face.probability > 0.0]
    if not faces:
        raise ConfigError(
            f"object {obj.name!r}: trimesh found no stable resting face (is the mesh closed and "
            "its centre of mass inside it?)"
        )
    return faces


def up_rotation(up: FloatArray, yaw: float = 0.0) -> FloatArray:
    """(3, 3) world-from-object rotation that takes the object-frame ``up`` to world +z, then
    turns by ``yaw`` [rad] about world z."""
    u = np.asarray(up, dtype=float)
    norm = float(np.linalg.norm(u))
    if not np.isfinite(norm) or norm < 1e-9:
        raise ConfigError(f"resting pose: 'up' must be a non-zero 3-vector, got {up!r}")
    u = u / norm
    # Any rotation taking u to z: z-row u, the other rows completing a right-handed frame.
    helper = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, u)
    x /= np.linalg.norm(x)
    R = np.vstack([x, np.cross(u, x), u])
    c, s = np.cos(yaw), np.sin(yaw)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    rotation: FloatArray = Rz @ R
    return rotation


def resting_pose(
    obj: ObjectModel, up: FloatArray, yaw: float, xy: tuple[float, float], top: float
) -> FloatArray:
    """(4, 4) world pose of the object resting with ``up`` to world +z, turned by ``yaw``
    [rad], its lowest mesh vertex on the plane z = ``top`` [m], its frame origin above (x, y)
    = ``xy`` [m]."""
    wMo = np.eye(4)
    wMo[:3, :3] = up_rotation(up, yaw)
    lowest = float((np.asarray(obj.mesh.vertices) @ wMo[:3, :3].T)[:, 2].min())
    wMo[:3, 3] = [xy[0], xy[1], top - lowest]
    return wMo
