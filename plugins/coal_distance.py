"""Reference contact estimator: coal distance queries between link and object geometry."""

from __future__ import annotations

import coal
import numpy as np
import numpy.typing as npt

from wholehand import defaults
from wholehand.contacts.base import ContactEstimator, ContactSet
from wholehand.errors import ConfigError
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel
from wholehand.models.poses import check_pose

FloatArray = npt.NDArray[np.float64]


def object_geometry(obj: ObjectModel) -> coal.CollisionGeometry:
    """coal geometry of an object in its canonical frame: the primitive itself, else a BVH mesh."""
    dims = obj.dimensions
    if obj.kind == "box":
        return coal.Box(*dims["size"])
    if obj.kind == "sphere":
        return coal.Sphere(dims["radius"])
    if obj.kind == "cylinder":
        return coal.Cylinder(dims["radius"], dims["height"])
    if obj.kind == "capsule":
        return coal.Capsule(dims["radius"], dims["length"])
    bvh = coal.BVHModelOBBRSS()
    bvh.beginModel(len(obj.mesh.faces), len(obj.mesh.vertices))
    bvh.addSubModel(np.asarray(obj.mesh.vertices, dtype=float), np.asarray(obj.mesh.faces))
    bvh.endModel()
    return bvh


class CoalDistanceEstimator(ContactEstimator):
    """One nearest point pair per link geometry and object, from coal distance queries.

    Differences from ``mesh_sdf``: each (link geometry, object) pair yields at most one contact,
    the witness point on the link at the signed minimum distance, so ``k`` has no effect beyond 1
    (a link with several geometries, e.g. a box and a fingertip sphere, can yield one per
    geometry); distances are exact for primitives (no grid). Penetration depth is exact between
    convex primitives; against a mesh object (BVH) coal reports penetrating pairs with a
    non-positive distance, so they are kept as contacts. It is a reference, not a fast path: one
    query per link geometry per cycle.

    Args:
        hand: the hand model (its collision geometry is queried).
        obj: the object model.
        d_thresh: contact threshold on the signed distance [m].
        links: optional link names to restrict candidates to.
    """

    def __init__(
        self,
        hand: HandModel,
        obj: ObjectModel,
        d_thresh: float = defaults.D_THRESH,
        k: int = 1,
        links: list[str] | None = None,
    ) -> None:
        if not d_thresh > 0.0:
            raise ConfigError(f"CoalDistanceEstimator: d_thresh must be > 0 [m], got {d_thresh!r}")
        if int(k) != k or k < 1:
            raise ConfigError(f"CoalDistanceEstimator: k must be an integer >= 1, got {k!r}")
        self.hand, self.obj, self.d_thresh = hand, obj, float(d_thresh)
        self._object_geom = object_geometry(obj)
        wanted = None if links is None else {hand.link_index(n) for n in links}
        frame_to_link = {int(f): i for i, f in enumerate(hand.link_frame)}
        self._pairs = []  # (link index, parent joint, joint-frame placement, distance functor)
        for geom in hand.collision_model.geometryObjects:
            link = frame_to_link.get(geom.parentFrame)
            if link is None or (wanted is not None and link not in wanted):
                continue
            functor = coal.ComputeDistance(geom.geometry, self._object_geom)
            self._pairs.append((link, geom.parentJoint, geom.placement.homogeneous, functor))
        self._request = coal.DistanceRequest()
        self._request.enable_signed_distance = True

    def estimate(
        self, kinematics: HandKinematics, wMo: FloatArray, stamp: float = 0.0
    ) -> ContactSet:
        wMo = check_pose(wMo, "wMo (object pose)")
        wMb = kinematics.wMb
        tf_object = coal.Transform3s(wMo[:3, :3].copy(), wMo[:3, 3].copy())
        rows = []
        for link, joint, jMg, functor in self._pairs:
            bMj = np.eye(4)
            bMj[:3, :3], bMj[:3, 3] = kinematics.bRj[joint], kinematics.bp_j[joint]
            wMg = wMb @ bMj @ jMg
            result = coal.DistanceResult()
            tf_geom = coal.Transform3s(wMg[:3, :3].copy(), wMg[:3, 3].copy())
            d = functor(tf_geom, tf_object, self._request, result)
            if d < self.d_thresh:
                # coal's normal points from the link (o1) to the object (o2).
                rows.append((result.getNearestPoint1(), -np.asarray(result.normal), link, d))
        hand = self.hand
        if not rows:
            return ContactSet.empty(hand.link_actuated, hand.link_fingertip, stamp)
        p, n, links, d = zip(*rows, strict=True)
        n_arr = np.asarray(n, dtype=float)
        n_arr /= np.linalg.norm(n_arr, axis=1, keepdims=True)
        return ContactSet(
            p_world=np.asarray(p, dtype=float),
            n_world=n_arr,
            link=np.asarray(links, dtype=np.intp),
            distance=np.asarray(d, dtype=float),
            link_actuated=hand.link_actuated,
            link_fingertip=hand.link_fingertip,
            stamp=stamp,
        )
