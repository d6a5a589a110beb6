"""Surface samples buried inside the hand's own collision shapes (``outer_surface_only``).

Collision shapes of a hand often overlap: two boxes of one palm, a finger's base inside the palm
housing. A sample on a shape's surface that lies inside another shape can never touch an object,
yet it would be a contact candidate every cycle. A sample is *buried* when it lies deeper than
``BURIED_DEPTH`` inside some collision shape of the hand in every one of a few configurations
(the zero pose clipped to the limits, the middle of the limits and ``RANDOM_POSES`` seeded
ones): shapes on the same rigid body overlap in every pose, shapes on different bodies only
where the joints keep them overlapping.

"Inside" needs a closed surface: shapes whose mesh is not watertight are skipped and counted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pinocchio as pin
import trimesh

from wholehand.models.surface import geometry_to_trimesh

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.intp]

BURIED_DEPTH = 5e-4
"""Depth inside a shape from which a sample counts as buried [m]: samples on a shape's own
surface (and shapes that merely touch) stay."""
RANDOM_POSES = 2
"""Seeded random configurations checked besides the zero and middle poses."""


@dataclass(frozen=True)
class BuriedSamples:
    """Result of :func:`find_buried_samples`."""

    buried: BoolArray
    """(P,) True for samples buried in every configuration checked."""
    skipped_shapes: list[str]
    """Names of the collision shapes that are not watertight and were not checked."""


def _shapes(geometry: pin.GeometryModel) -> tuple[list[trimesh.Trimesh], list[int], list[str]]:
    """Closed collision shapes in their parent joints' frames, those joints, and the names of
    the shapes that are not closed."""
    meshes, joints, skipped = [], [], []
    for obj in geometry.geometryObjects:
        mesh = geometry_to_trimesh(obj)
        if not mesh.is_watertight:
            skipped.append(obj.name)
            continue
        mesh.apply_transform(obj.placement.homogeneous)  # into the parent joint's frame
        meshes.append(mesh)
        joints.append(int(obj.parentJoint))
    return meshes, joints, skipped


def _inside(mesh: trimesh.Trimesh, points: FloatArray) -> BoolArray:
    """(P,) points deeper than BURIED_DEPTH inside a watertight mesh (mesh frame)."""
    out = np.zeros(len(points), dtype=bool)
    lo, hi = mesh.bounds
    near = np.flatnonzero(np.all((points > lo) & (points < hi), axis=1))
    if near.size == 0:
        return out
    inside = near[mesh.contains(points[near])]
    if inside.size:
        _, depth, _ = trimesh.proximity.closest_point(mesh, points[inside])
        out[inside[depth > BURIED_DEPTH]] = True
    return out


def find_buried_samples(
    model: pin.Model,
    geometry: pin.GeometryModel,
    p_joint: FloatArray,
    joint: IntArray,
    seed: int = 0,
) -> BuriedSamples:
    """Which surface samples are buried inside the hand's collision shapes.

    Args:
        model: the hand's Pinocchio model; geometry: its collision geometry.
        p_joint: (P, 3) samples in the frames of their parent joints [m]; joint: (P,) those
            joints' indices.
        seed: seeds the random configurations.
    """
    meshes, shape_joints, skipped = _shapes(geometry)
    buried = np.ones(len(p_joint), dtype=bool)
    if not meshes:
        return BuriedSamples(np.zeros(len(p_joint), dtype=bool), skipped)
    lower = np.asarray(model.lowerPositionLimit, dtype=float)
    upper = np.asarray(model.upperPositionLimit, dtype=float)
    finite = np.isfinite(lower) & np.isfinite(upper)
    middle = pin.neutral(model)
    middle[finite] = 0.5 * (lower[finite] + upper[finite])
    rng = np.random.default_rng(seed)
    poses = [np.clip(pin.neutral(model), lower, upper), middle]
    for _ in range(RANDOM_POSES):
        q = middle.copy()
        q[finite] = rng.uniform(lower[finite], upper[finite])
        poses.append(q)
    data = model.createData()
    for q in poses:
        pin.forwardKinematics(model, data, q)
        bMj = np.array([data.oMi[j].homogeneous for j in range(model.njoints)])
        p_base = np.einsum("pab,pb->pa", bMj[joint, :3, :3], p_joint) + bMj[joint, :3, 3]
        inside = np.zeros(len(p_joint), dtype=bool)
        for mesh, j in zip(meshes, shape_joints, strict=True):
            jMb = np.linalg.inv(bMj[j])
            candidates = np.flatnonzero(buried & ~inside)
            local = p_base[candidates] @ jMb[:3, :3].T + jMb[:3, 3]
            inside[candidates[_inside(mesh, local)]] = True
        buried &= inside
        if not buried.any():
            break
    return BuriedSamples(buried, skipped)
