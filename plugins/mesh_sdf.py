"""The paper's contact estimator: hand surface samples looked up in the object's SDF grid."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from wholehand import defaults
from wholehand.contacts.base import ContactEstimator, ContactSet
from wholehand.contacts.selection import top_k_per_link
from wholehand.errors import ConfigError
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel
from wholehand.models.poses import check_pose, inverse

FloatArray = npt.NDArray[np.float64]


class MeshSDFEstimator(ContactEstimator):
    """Whole-hand contacts from link surface samples against the object SDF (paper Sec. III-B).

    Per cycle: the joint placements from one forward-kinematics pass move the samples into the
    object frame; links whose bounding sphere is farther than ``d_thresh`` from the object's
    bounding sphere are skipped; the rest are looked up in the SDF grid by trilinear
    interpolation; points with signed distance below ``d_thresh`` are candidates, at most ``k``
    per link (closest first); gradients (normals) are computed for the kept points only.

    Args:
        hand: the hand model (its surface samples are the candidates).
        obj: the object model (its SDF grid is queried).
        d_thresh: contact threshold on the signed distance [m].
        k: maximum contacts per link.
        links: optional link names to restrict candidates to (e.g. the fingertip links).
    """

    def __init__(
        self,
        hand: HandModel,
        obj: ObjectModel,
        d_thresh: float = defaults.D_THRESH,
        k: int = defaults.K_PER_LINK,
        links: list[str] | None = None,
    ) -> None:
        if not d_thresh > 0.0:
            raise ConfigError(f"MeshSDFEstimator: d_thresh must be > 0 [m], got {d_thresh!r}")
        if int(k) != k or k < 1:
            raise ConfigError(f"MeshSDFEstimator: k must be an integer >= 1, got {k!r}")
        self.hand, self.obj = hand, obj
        self.d_thresh, self.k = float(d_thresh), int(k)
        self.sdf = obj.sdf
        samples = hand.samples
        keep = np.ones(len(samples), dtype=bool)
        if links is not None:
            wanted = [hand.link_index(name) for name in links]
            keep = np.isin(samples.link, wanted)
        self._p = np.ascontiguousarray(samples.p_joint[keep])
        self._joint = samples.joint[keep]
        self._link = samples.link[keep]
        # Bounding sphere of each link's samples in its joint frame, for culling.
        n_links = len(hand.link_names)
        self._link_joint = hand.link_joint
        self._centre = np.zeros((n_links, 3))
        self._radius = np.full(n_links, -np.inf)  # links without candidates are always culled
        for i in np.unique(self._link):
            pts = self._p[self._link == i]
            c = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
            self._centre[i] = c
            self._radius[i] = np.linalg.norm(pts - c, axis=1).max()
        verts = np.asarray(obj.mesh.vertices)
        self._obj_centre = 0.5 * (verts.min(axis=0) + verts.max(axis=0))
        self._obj_radius = float(np.linalg.norm(verts - self._obj_centre, axis=1).max())
        # Rows of the samples per link, so that culled links cost nothing.
        order = np.argsort(self._link, kind="stable")
        self._p, self._joint, self._link = self._p[order], self._joint[order], self._link[order]
        bounds = np.searchsorted(self._link, np.arange(n_links + 1))
        self._rows = [np.arange(bounds[i], bounds[i + 1]) for i in range(n_links)]

    def estimate(self, kinematics: HandKinematics, wMo: FloatArray, stamp: float = 0.0) -> ContactSet:
        wMo = check_pose(wMo, "wMo (object pose)")
        oMw = inverse(wMo)
        R, t = kinematics.joint_poses_in(oMw)
        # Cull links whose bounding sphere cannot come within d_thresh of the object.
        centres = np.einsum("lab,lb->la", R[self._link_joint], self._centre) + t[self._link_joint]
        gap = np.linalg.norm(centres - self._obj_centre, axis=1) - self._radius - self._obj_radius
        near = np.flatnonzero(gap < self.d_thresh)
        hand = self.hand
        if near.size == 0:
            return ContactSet.empty(hand.link_actuated, hand.link_fingertip, stamp)
        rows = np.concatenate([self._rows[i] for i in near])
        if rows.size == 0:
            return ContactSet.empty(hand.link_actuated, hand.link_fingertip, stamp)
        joint = self._joint[rows]
        p_obj = np.einsum("pab,pb->pa", R[joint], self._p[rows]) + t[joint]
        d = self.sdf.query(p_obj)
        close = np.flatnonzero(d < self.d_thresh)
        keep = close[top_k_per_link(self._link[rows[close]], d[close], self.k)]
        if keep.size == 0:
            return ContactSet.empty(hand.link_actuated, hand.link_fingertip, stamp)
        p_kept = p_obj[keep]
        d_kept, grad = self.sdf.query_with_gradient(p_kept)
        wRo = wMo[:3, :3]
        return ContactSet(
            p_world=p_kept @ wRo.T + wMo[:3, 3],
            n_world=grad @ wRo.T,
            link=self._link[rows[keep]],
            distance=np.asarray(d_kept, dtype=float),
            link_actuated=hand.link_actuated,
            link_fingertip=hand.link_fingertip,
            stamp=stamp,
        )
