"""The paper's contact estimator: hand surface samples looked up in the object's SDF grid."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from wholehand_plugins.mesh_sdf.kernels import mesh_sdf_contacts

from wholehand import defaults
from wholehand.contacts.base import ContactEstimator, ContactSet
from wholehand.errors import ConfigError
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel
from wholehand.models.poses import check_pose
from wholehand.models.sdf_lookup import grid_arguments
from wholehand.models.surface import farthest_point_sampling

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


CLUSTER_SIZE = 24
"""Average number of samples per culling cluster."""


class MeshSDFEstimator(ContactEstimator):
    """Whole-hand contacts from link surface samples against the object SDF (paper Sec. III-B).

    Per cycle: one set of joint placements (from the kinematics' forward pass) moves the
    samples into the object frame; points with signed distance below ``d_thresh`` are
    candidates, at most ``k`` per link, closest first; normals come from the SDF gradient at the
    kept points only.

    Hysteresis: a sample selected last cycle keeps its place unless a candidate of its link is
    more than ``hysteresis`` closer to the surface (it still drops out past ``d_thresh``), so
    the contacts, and with them the QP and its warm start, do not jump between neighbouring
    samples from one cycle to the next. The estimator remembers last cycle's samples;
    :meth:`reset` forgets them.

    Culling (exact, it never drops a candidate): the samples of each link are grouped into
    clusters of about ``CLUSTER_SIZE`` points with a bounding sphere each. The SDF is
    1-Lipschitz, so a cluster whose centre lies farther than ``d_thresh + radius + 2 * spacing``
    from the surface (the last term covers the interpolation error at both ends) holds no
    candidate; only the points of the remaining clusters are transformed and looked up.

    The whole cycle runs in one compiled kernel (:func:`wholehand_plugins.mesh_sdf.kernels.
    mesh_sdf_contacts`; ``wholehand bench contacts`` times it); its lookups equal
    :meth:`SignedDistanceGrid.query` and :meth:`~SignedDistanceGrid.query_with_gradient` to the
    last bit. The first call in a fresh
    environment compiles it (seconds; cached on disk afterwards, see that module). The kernel
    releases the GIL and keeps no state between calls.

    Args:
        hand: the hand model (its surface samples are the candidates).
        obj: the object model (its SDF grid is queried).
        d_thresh: contact threshold on the signed distance [m].
        k: maximum contacts per link.
        links: optional link names to restrict candidates to (e.g. the fingertip links).
        hysteresis: margin [m] by which a new sample must be closer than a kept one to take its
            place (:data:`wholehand.defaults.CONTACT_HYSTERESIS`; 0: the paper's selection).
    """

    def __init__(
        self,
        hand: HandModel,
        obj: ObjectModel,
        d_thresh: float = defaults.D_THRESH,
        k: int = defaults.K_PER_LINK,
        links: list[str] | None = None,
        hysteresis: float = defaults.CONTACT_HYSTERESIS,
    ) -> None:
        if not d_thresh > 0.0:
            raise ConfigError(f"MeshSDFEstimator: d_thresh must be > 0 [m], got {d_thresh!r}")
        if not 0.0 <= hysteresis < d_thresh:
            raise ConfigError(
                f"MeshSDFEstimator: hysteresis must be >= 0 and below d_thresh = {d_thresh} "
                f"[m], got {hysteresis!r}"
            )
        self.hysteresis = float(hysteresis)
        if int(k) != k or k < 1:
            raise ConfigError(f"MeshSDFEstimator: k must be an integer >= 1, got {k!r}")
        self.hand, self.obj = hand, obj
        self.d_thresh, self.k = float(d_thresh), int(k)
        self.sdf = obj.sdf
        # Points beyond the grid are never candidates, which needs the grid to reach d_thresh.
        lo, hi = np.asarray(obj.mesh.bounds)
        margin = min((lo - self.sdf.bounds[0]).min(), (self.sdf.bounds[1] - hi).min())
        if self.d_thresh >= margin:
            raise ConfigError(
                f"MeshSDFEstimator: d_thresh = {d_thresh} m reaches past the SDF grid of "
                f"{obj.name!r} (margin {margin:.3f} m); build the object with a larger sdf_padding"
            )
        samples = hand.samples
        keep = np.ones(len(samples), dtype=bool)
        if links is not None:
            keep = np.isin(samples.link, [hand.link_index(name) for name in links])
        p, joint, link = samples.p_joint[keep], samples.joint[keep], samples.link[keep]
        cluster = np.empty(len(p), dtype=np.intp)
        centres: list[FloatArray] = []
        radii: list[float] = []
        cluster_joint: list[int] = []
        for i in np.unique(link):
            rows = np.flatnonzero(link == i)
            pts = p[rows]
            seeds = pts[farthest_point_sampling(pts, -(-len(rows) // CLUSTER_SIZE))]
            member = np.argmin(((pts[:, None, :] - seeds[None]) ** 2).sum(axis=2), axis=1)
            for m in np.unique(member):
                cluster[rows[member == m]] = len(centres)
                c = pts[member == m].mean(axis=0)
                centres.append(c)
                radii.append(np.linalg.norm(pts[member == m] - c, axis=1).max())
                cluster_joint.append(joint[rows[0]])
        order = np.argsort(cluster, kind="stable")
        self._p = np.ascontiguousarray(p[order])
        self._joint = np.ascontiguousarray(joint[order], dtype=np.intp)
        self._link = np.ascontiguousarray(link[order], dtype=np.intp)
        self._cluster = cluster[order]
        self._centre = np.ascontiguousarray(np.asarray(centres, dtype=np.float64).reshape(-1, 3))
        self._reach = np.asarray(radii, dtype=np.float64) + 2.0 * self.sdf.spacing + self.d_thresh
        self._cluster_joint = np.asarray(cluster_joint, dtype=np.intp)
        # The kernel's layout: rows of a cluster contiguous (cluster_start), clusters numbered
        # link by link, so rows of a link are contiguous too (its top-K runs in one pass).
        bounds = np.arange(self.n_clusters + 1)
        self._cluster_start = np.searchsorted(self._cluster, bounds).astype(np.intp)
        assert np.all(np.diff(self._link) >= 0), "clusters are numbered link by link"
        # A link hangs from one joint, so its clusters' samples share the cluster's joint.
        assert np.array_equal(self._joint, self._cluster_joint[self._cluster])
        self._grid = grid_arguments(self.sdf)
        self._n_joints = int(hand.model.njoints)
        self._kept = np.zeros(len(self._p), dtype=np.bool_)
        self.rows: IntArray = np.zeros(0, dtype=np.intp)
        """Sample rows of the last cycle's contacts (the estimator's own numbering)."""
        self.reset()

    def reset(self) -> None:
        self._kept[self.rows] = False
        self.rows = np.zeros(0, dtype=np.intp)

    @property
    def n_clusters(self) -> int:
        """Number of culling clusters."""
        return int(self._centre.shape[0])

    def estimate(
        self, kinematics: HandKinematics, wMo: FloatArray, stamp: float = 0.0
    ) -> ContactSet:
        wMo = check_pose(wMo, "wMo (object pose)")
        if kinematics.bRj.shape[0] != self._n_joints:
            raise ConfigError(
                f"MeshSDFEstimator.estimate: kinematics of hand {kinematics.hand.name!r} "
                f"({kinematics.bRj.shape[0]} joints) given to an estimator built for hand "
                f"{self.hand.name!r} ({self._n_joints} joints)"
            )
        p_world, n_world, link, distance, rows = self._kernel(kinematics, wMo)
        self._kept[self.rows] = False
        self._kept[rows] = True
        self.rows = rows
        hand = self.hand
        return ContactSet(
            p_world=p_world,
            n_world=n_world,
            link=link,
            distance=distance,
            link_actuated=hand.link_actuated,
            link_fingertip=hand.link_fingertip,
            stamp=stamp,
        )

    def _kernel(
        self, kinematics: HandKinematics, wMo: FloatArray
    ) -> tuple[FloatArray, FloatArray, IntArray, FloatArray, IntArray]:
        """Points, normals, links, distances and sample rows of the selected contacts (the
        compiled pass)."""
        return mesh_sdf_contacts(
            np.ascontiguousarray(wMo),
            np.ascontiguousarray(kinematics.wMb),
            kinematics.bRj,
            kinematics.bp_j,
            self._p,
            self._link,
            self._cluster_start,
            self._centre,
            self._reach,
            self._cluster_joint,
            *self._grid,
            self.d_thresh,
            self.k,
            self._kept,
            self.hysteresis,
        )
