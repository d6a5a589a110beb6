"""Kinematics of a batch of hand configurations at once, in one frame (an object's).

The grasp optimiser moves many hands about one object together (:mod:`wholehand.grasps.synthesis`):
per configuration one Pinocchio pass (placements and the spatial Jacobian), then every query
over the whole batch in numpy or one compiled kernel. Frames: ``b`` the hand base (the URDF
root), ``o`` the frame the batch is posed in (``oMb`` per configuration), ``j`` a joint frame.
"""

from __future__ import annotations

from typing import cast

import numba
import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.jit import CACHE
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import PlacementViewsOwner, placement_views

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]


def cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a x b`` over the last axis of two broadcastable (..., 3) arrays: the products and
    differences ``np.cross`` computes, without its axis handling (tens of microseconds a call,
    a fifth of a batch's energy before it)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


class BatchKinematics(PlacementViewsOwner):
    """Joint placements and Jacobian columns of ``B`` configurations of one hand.

    Call :meth:`update` with the batch; the queries read that pass.

    Attributes (after :meth:`update`):
        R: (B, J, 3, 3) joint rotations in frame o.
        t: (B, J, 3) joint origins in frame o [m].
        v, w: (B, n_v, 3) each velocity dimension's spatial Jacobian column in frame o, about
            o's origin: a point ``p`` (o frame) moved by dimension ``k`` (and only such a point,
            see :attr:`support`) moves at ``v[k] + w[k] x p`` [m/rad] and turns at ``w[k]``.
    """

    def __init__(self, hand: HandModel) -> None:
        self.hand = hand
        self.model = hand.model
        self.data = hand.model.createData()
        model = self.model
        self.support = np.zeros((model.njoints, model.nv))
        """(J, n_v): 1 where velocity dimension k moves joint j (and what is attached to it)."""
        for j in range(1, model.njoints):
            for s in model.supports[j]:
                if s > 0:
                    jm = model.joints[s]
                    self.support[j, jm.idx_v : jm.idx_v + jm.nv] = 1.0
        self._placements = placement_views(self.data)
        self.R = np.zeros((0, model.njoints, 3, 3))
        self.t = np.zeros((0, model.njoints, 3))
        self.v = np.zeros((0, model.nv, 3))
        self.w = np.zeros((0, model.nv, 3))
        self.oMb = np.zeros((0, 4, 4))

    @property
    def size(self) -> int:
        """Configurations in the batch."""
        return int(self.oMb.shape[0])

    def update(self, q: FloatArray, oMb: FloatArray) -> None:
        """One pass at joint positions ``q`` (B, n_q) [rad] with base poses ``oMb`` (B, 4, 4)."""
        model, data = self.model, self.data
        n = q.shape[0]
        bR = np.empty((n, model.njoints, 3, 3))
        bp = np.empty((n, model.njoints, 3))
        J = np.empty((n, 6, model.nv))
        for b in range(n):
            pin.computeJointJacobians(model, data, q[b])
            J[b] = data.J
            if self._placements is not None:
                bR[b], bp[b] = self._placements
            else:
                each = np.array([M.homogeneous for M in data.oMi])
                bR[b], bp[b] = each[:, :3, :3], each[:, :3, 3]
        oRb, ot = oMb[:, :3, :3], oMb[:, :3, 3]
        self.oMb = oMb.copy()
        self.R = np.matmul(oRb[:, None], bR)
        self.t = np.einsum("bac,bjc->bja", oRb, bp) + ot[:, None]
        self.w = np.einsum("bac,bck->bka", oRb, J[:, 3:])
        self.v = np.einsum("bac,bck->bka", oRb, J[:, :3]) + cross(ot[:, None], self.w)

    def transform(self, p_joint: FloatArray, joint: IntArray) -> FloatArray:
        """(B, P, 3) points ``p_joint`` (P, 3) [m], each given in the frame of joint
        ``joint[i]``, in frame o for every configuration."""
        return cast(
            FloatArray,
            _transform_batch(
                self.R, self.t, np.ascontiguousarray(p_joint, dtype=np.float64), joint
            ),
        )

    def transform_each(self, p_joint: FloatArray, joint: IntArray, pick: IntArray) -> FloatArray:
        """(B, N, 3) points in frame o: for configuration ``b``, the points ``pick[b]`` (B, N)
        of ``p_joint`` (P, 3) [m] (each in the frame of joint ``joint[i]``), as
        :meth:`transform` places them."""
        return cast(
            FloatArray,
            _transform_picked(
                self.R,
                self.t,
                np.ascontiguousarray(p_joint, dtype=np.float64),
                joint,
                np.ascontiguousarray(pick, dtype=np.intp),
            ),
        )

    def transform_groups(
        self,
        p_joint: FloatArray,
        joint: IntArray,
        groups: tuple[IntArray, IntArray],
        chosen: BoolArray,
    ) -> tuple[FloatArray, IntArray]:
        """The points of chosen groups of ``p_joint`` (P, 3) [m] in frame o, as
        :meth:`transform` places them: ``groups`` is (bounds, members), group ``g`` holding
        points ``members[bounds[g]:bounds[g + 1]]``, and ``chosen`` (B, G) says which groups
        of each configuration. Returns the (K, 3) points and their flat indices ``b * P + i``
        into :meth:`transform`'s (B, P) output, configuration by configuration, each in
        group order."""
        bounds, members = groups
        points, flat = _transform_groups(
            self.R,
            self.t,
            np.ascontiguousarray(p_joint, dtype=np.float64),
            joint,
            bounds,
            members,
            np.ascontiguousarray(chosen, dtype=np.bool_),
        )
        return cast(FloatArray, points), cast(IntArray, flat)

    def rotate(self, n_joint: FloatArray, joint: IntArray) -> FloatArray:
        """(B, N, 3) directions: ``n_joint`` (B, N, 3) given in the frames of joints ``joint``
        (B, N), in frame o."""
        rows = np.arange(self.size)[:, None]
        return cast(FloatArray, np.einsum("bnac,bnc->bna", self.R[rows, joint], n_joint))

    def generalized_forces(
        self,
        batch: IntArray,
        joint: IntArray,
        points: FloatArray,
        forces: FloatArray,
        moments: FloatArray | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The sums that a set of point forces makes per configuration: the force and the
        moment about the base origin, and the generalised force on each velocity dimension.

        Args:
            batch: (N,) configuration of each point.
            joint: (N,) the joint each point is attached to.
            points: (N, 3) the points in frame o [m].
            forces: (N, 3) a force on each point, frame o [N, or any energy gradient dE/dp].
            moments: (N, 3) a pure moment on the joint of each point (a direction ``m`` with
                gradient ``g`` turns as ``omega x m``: moment ``m x g``), or None.

        Returns:
            (B, 3) the forces' sum; (B, 3) their moment about each base origin; (B, n_v) the
            generalised forces ``J^T f`` of each configuration.
        """
        n, nj = self.size, self.model.njoints
        cell = batch * nj + joint
        moment = cross(points, forces)
        if moments is not None:
            moment += moments
        pairs = np.concatenate((forces, moment), axis=1)  # (N, 6)
        sums = np.empty((n * nj, 6))
        for c in range(6):
            sums[:, c] = np.bincount(cell, weights=pairs[:, c], minlength=n * nj)
        sums = sums.reshape(n, nj, 6)
        per_dim = np.einsum("jk,bjc->bkc", self.support, sums)  # (B, n_v, 6): subtree sums
        tau = np.einsum("bkc,bkc->bk", self.v, per_dim[..., :3])
        tau += np.einsum("bkc,bkc->bk", self.w, per_dim[..., 3:])
        force, moment_o = sums[..., :3].sum(axis=1), sums[..., 3:].sum(axis=1)
        about_base = moment_o - cross(self.oMb[:, :3, 3], force)
        return force, about_base, tau


@numba.njit(cache=CACHE, nogil=True, inline="always")
def _place(
    R: FloatArray, t: FloatArray, p_joint: FloatArray, b: int, j: int, i: int, out: FloatArray
) -> None:  # pragma: no cover - jit
    """``out[:] = R[b, j] p_joint[i] + t[b, j]``, as :func:`_transform_batch` computes it."""
    x, y, z = p_joint[i, 0], p_joint[i, 1], p_joint[i, 2]
    for a in range(3):
        out[a] = R[b, j, a, 0] * x + R[b, j, a, 1] * y + R[b, j, a, 2] * z + t[b, j, a]


@numba.njit(cache=CACHE, nogil=True)
def _transform_batch(
    R: FloatArray, t: FloatArray, p_joint: FloatArray, joint: IntArray
) -> FloatArray:  # pragma: no cover - jit
    """(B, P, 3) points ``R[b, joint[i]] p_joint[i] + t[b, joint[i]]``."""
    n, m = R.shape[0], p_joint.shape[0]
    out = np.empty((n, m, 3))
    for b in range(n):
        for i in range(m):
            _place(R, t, p_joint, b, joint[i], i, out[b, i])
    return out


@numba.njit(cache=CACHE, nogil=True)
def _transform_picked(
    R: FloatArray, t: FloatArray, p_joint: FloatArray, joint: IntArray, pick: IntArray
) -> FloatArray:  # pragma: no cover - jit
    """(B, N, 3) points ``R[b, joint[i]] p_joint[i] + t[b, joint[i]]`` for ``i = pick[b, k]``."""
    n, m = pick.shape
    out = np.empty((n, m, 3))
    for b in range(n):
        for k in range(m):
            i = pick[b, k]
            _place(R, t, p_joint, b, joint[i], i, out[b, k])
    return out


@numba.njit(cache=CACHE, nogil=True)
def _transform_groups(
    R: FloatArray,
    t: FloatArray,
    p_joint: FloatArray,
    joint: IntArray,
    bounds: IntArray,
    members: IntArray,
    chosen: BoolArray,
) -> tuple[FloatArray, IntArray]:  # pragma: no cover - jit
    """:meth:`BatchKinematics.transform_groups`."""
    n, m = chosen.shape[0], p_joint.shape[0]
    total = 0
    for b in range(n):
        for g in range(chosen.shape[1]):
            if chosen[b, g]:
                total += bounds[g + 1] - bounds[g]
    points = np.empty((total, 3))
    flat = np.empty(total, dtype=np.intp)
    row = 0
    for b in range(n):
        for g in range(chosen.shape[1]):
            if not chosen[b, g]:
                continue
            for k in range(bounds[g], bounds[g + 1]):
                i = members[k]
                _place(R, t, p_joint, b, joint[i], i, points[row])
                flat[row] = b * m + i
                row += 1
    return points, flat
