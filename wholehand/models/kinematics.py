"""Per-cycle hand kinematics: one forward pass, batched point transforms, point Jacobians.

Frames: ``b`` is the hand base (the URDF root, Pinocchio's "world" of the hand model), ``w`` the
world, ``j`` a joint frame. Pinocchio runs in the base frame; results are mapped to the world
with the mount pose ``wMb``.
"""

from __future__ import annotations

from typing import cast

import numba
import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.errors import ConfigError
from wholehand.jit import CACHE, fma
from wholehand.models.hand import HandModel
from wholehand.models.poses import check_pose

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


_IDENTITY = np.eye(4)


class PlacementViewsOwner:
    """Owns a Pinocchio ``data`` and read-only views of its joint placements
    (:func:`placement_views`): a pickled copy makes views of its own data, not the original's."""

    data: pin.Data
    _placements: tuple[FloatArray, FloatArray] | None

    def __getstate__(self) -> dict[str, object]:
        state = self.__dict__.copy()
        state["_placements"] = None  # views into this object's Pinocchio data, not a copy's
        return state

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        self._placements = placement_views(self.data)


class HandKinematics(PlacementViewsOwner):
    """Kinematic state of a hand at one configuration (wraps Pinocchio model and data).

    Call :meth:`update` once per cycle; every query afterwards reuses that pass.
    """

    def __init__(self, hand: HandModel) -> None:
        self.hand = hand
        self.model = hand.model
        self.data = hand.model.createData()
        n_joints = self.model.njoints
        # support[j, k]: velocity dimension k moves joint j (and everything attached to it).
        self._support = np.zeros((n_joints, self.model.nv))
        for j in range(1, n_joints):
            for s in self.model.supports[j]:
                if s > 0:
                    jm = self.model.joints[s]
                    self._support[j, jm.idx_v : jm.idx_v + jm.nv] = 1.0
        self.q = pin.neutral(self.model)
        self.q.setflags(write=False)
        self.wMb = hand.wMb.copy()
        self.bRj = np.zeros((n_joints, 3, 3))
        self.bp_j = np.zeros((n_joints, 3))
        self._jacobians_fresh = False
        self._placements = placement_views(self.data)
        self.update(self.q, self.wMb)
        # Load the compiled kernels now rather than in a control cycle.
        first = np.zeros(1, dtype=np.intp)
        origin = self.transform_points(np.zeros((1, 3)), first)
        self.point_jacobians(first, origin)
        self.from_joint_frames(*self.to_joint_frames(origin, np.zeros((1, 3)), first), first)

    def update(self, q: npt.ArrayLike, wMb: FloatArray | None = None) -> None:
        """Run forward kinematics at joint positions ``q`` (n_q,) with base pose ``wMb`` (4, 4)."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self.hand.nq,):
            raise ConfigError(
                f"HandKinematics.update: q has shape {q.shape}, hand {self.hand.name!r} "
                f"needs ({self.model.nq},)"
            )
        if not np.isfinite(q).all():
            raise ConfigError(f"HandKinematics.update: q contains NaN or inf: {q.tolist()}")
        if wMb is not None:
            self.wMb = check_pose(wMb, "wMb (hand base pose)")
        self.q = q.copy()
        self.q.setflags(write=False)
        pin.forwardKinematics(self.model, self.data, self.q)
        if self._placements is not None:
            np.copyto(self.bRj, self._placements[0])
            np.copyto(self.bp_j, self._placements[1])
        else:  # one 4x4 per joint out of Pinocchio (each access crosses into Python)
            placements = np.array([oMi.homogeneous for oMi in self.data.oMi])
            self.bRj[:] = placements[:, :3, :3]
            self.bp_j[:] = placements[:, :3, 3]
        self._jacobians_fresh = False

    def joint_poses_in(self, fMw: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Rotations (J, 3, 3) and translations (J, 3) of every joint frame in frame f.

        Args:
            fMw: (4, 4) pose of the world in frame f (e.g. ``oMw`` for the object frame).
        """
        fMw = np.ascontiguousarray(fMw, dtype=np.float64)
        return cast(tuple[FloatArray, FloatArray], _joint_poses(fMw, self.wMb, self.bRj, self.bp_j))

    def transform_points(
        self, p_joint: FloatArray, joint: IntArray, fMw: FloatArray | None = None
    ) -> FloatArray:
        """Points given in their joint frames, moved to frame f (world if ``fMw`` is None).

        Args:
            p_joint: (P, 3) points, each in the frame of joint ``joint[i]`` [m].
            joint: (P,) joint index of each point.
            fMw: (4, 4) pose of the world in the target frame.
        """
        fMw = _IDENTITY if fMw is None else np.ascontiguousarray(fMw, dtype=np.float64)
        R, t = _joint_poses(fMw, self.wMb, self.bRj, self.bp_j)
        p_joint = _c_floats(p_joint)
        return cast(FloatArray, _transform(R, t, p_joint, np.asarray(joint, dtype=np.intp)))

    def to_joint_frames(
        self, p_world: FloatArray, n_world: FloatArray, joint: IntArray
    ) -> tuple[FloatArray, FloatArray]:
        """Points (P, 3) [m] and directions (P, 3) given in the world, each expressed in the
        frame of joint ``joint[i]`` (the inverse of :meth:`from_joint_frames`)."""
        R, t = _joint_poses(_IDENTITY, self.wMb, self.bRj, self.bp_j)
        p, n = _c_floats(p_world), _c_floats(n_world)
        joint = np.ascontiguousarray(joint, dtype=np.intp)
        return cast(tuple[FloatArray, FloatArray], _to_joint_frames(R, t, joint, p, n))

    def from_joint_frames(
        self, p_joint: FloatArray, n_joint: FloatArray, joint: IntArray
    ) -> tuple[FloatArray, FloatArray]:
        """Points (P, 3) [m] and directions (P, 3), each given in the frame of joint
        ``joint[i]``, in the world at this configuration."""
        R, t = _joint_poses(_IDENTITY, self.wMb, self.bRj, self.bp_j)
        p, n = _c_floats(p_joint), _c_floats(n_joint)
        joint = np.ascontiguousarray(joint, dtype=np.intp)
        return cast(tuple[FloatArray, FloatArray], _from_joint_frames(R, t, joint, p, n))

    def frame_pose(self, link: str) -> FloatArray:
        """(4, 4) world pose of a URDF link frame."""
        fid = self.model.getFrameId(link, pin.FrameType.BODY)
        pin.updateFramePlacement(self.model, self.data, fid)
        return cast(FloatArray, self.wMb @ self.data.oMf[fid].homogeneous)

    def point_jacobians(self, joint: IntArray, p_world: FloatArray) -> FloatArray:
        """Linear-velocity Jacobians of hand points rigidly attached to given joints.

        Args:
            joint: (N,) parent joint of each point.
            p_world: (N, 3) points in the world [m].

        Returns:
            (N, 3, n_v): d(point velocity, world axes) / d(joint velocity). One Jacobian pass
            per cycle; each point Jacobian shifts the joint's spatial Jacobian to the point.
        """
        if not self._jacobians_fresh:
            pin.computeJointJacobians(self.model, self.data, self.q)
            self._jacobians_fresh = True
        p_world = np.ascontiguousarray(p_world, dtype=np.float64)
        joint = np.asarray(joint, dtype=np.intp)
        return cast(
            FloatArray, _point_jacobians(self.data.J, self.wMb, p_world, joint, self._support)
        )

    def angular_jacobians(self, joint: IntArray) -> FloatArray:
        """Angular-velocity Jacobians of the frames of given joints (and of any point or
        direction rigidly attached to them).

        Args:
            joint: (N,) joint index.

        Returns:
            (N, 3, n_v): d(angular velocity, world axes) / d(joint velocity); a direction ``m``
            attached to joint ``joint[i]`` turns as ``dm/dq_k = J[i, :, k] x m``.
        """
        if not self._jacobians_fresh:
            pin.computeJointJacobians(self.model, self.data, self.q)
            self._jacobians_fresh = True
        joint = np.asarray(joint, dtype=np.intp)
        base = self.data.J[3:6][None, :, :] * self._support[joint][:, None, :]  # (N, 3, n_v)
        return cast(FloatArray, np.einsum("ab,nbk->nak", self.wMb[:3, :3], base))

    def actuation_jacobians(self, joint: IntArray, p_world: FloatArray) -> FloatArray:
        """Point Jacobians in the coordinates allocators work in (see
        :attr:`~wholehand.models.hand.HandModel.n_actuation`).

        Returns:
            (N, 3, n_actuation): for a coupled hand ``J C``, the velocity of each point per
            actuator velocity (``C`` of :mod:`wholehand.models.coupling`); otherwise
            :meth:`point_jacobians` unchanged.
        """
        J = self.point_jacobians(joint, p_world)
        return J @ self.hand.coupling if self.hand.coupled else J


def _c_floats(a: npt.ArrayLike) -> FloatArray:
    """``a`` as C-ordered, writable float64 (copied only when it is not): the one layout the
    kernels are loaded for, so that no other version loads in a cycle."""
    out = np.ascontiguousarray(a, dtype=np.float64)
    return out if out.flags.writeable else out.copy()


def placement_views(data: pin.Data) -> tuple[FloatArray, FloatArray] | None:
    """Read-only views (J, 3, 3) and (J, 3) of every joint's placement in Pinocchio's ``data``
    (``data.oMi``: rotations and translations in the base frame), or None where they cannot be
    had.

    Pinocchio keeps the placements in one ``std::vector`` of SE3, so each one's rotation and
    translation sit at a fixed step in memory; a strided view over them follows every forward
    pass, and copying it replaces a Python loop over the joints (about 13 us a cycle). The
    layout is checked here, address by address and value by value; where it differs (another
    Pinocchio build), None, and the caller reads the placements one by one.
    """
    oMi = data.oMi
    n = len(oMi)

    def address(a: FloatArray) -> int:
        return int(a.__array_interface__["data"][0])

    R0, t0 = oMi[0].rotation, oMi[0].translation
    if n < 2 or R0.shape != (3, 3) or t0.shape != (3,) or R0.dtype != np.float64:
        return None
    step = address(oMi[1].rotation) - address(R0)
    for j in range(n):
        if address(oMi[j].rotation) != address(R0) + j * step:
            return None
        if address(oMi[j].translation) != address(t0) + j * step:
            return None
    R = np.lib.stride_tricks.as_strided(R0, (n, 3, 3), (step, *R0.strides), writeable=False)
    t = np.lib.stride_tricks.as_strided(t0, (n, 3), (step, *t0.strides), writeable=False)
    each = np.array([oMi[j].homogeneous for j in range(n)])
    if not (np.array_equal(R, each[:, :3, :3]) and np.array_equal(t, each[:, :3, 3])):
        return None
    return R, t


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def _point_jacobians(
    J: FloatArray, wMb: FloatArray, p_world: FloatArray, joint: IntArray, support: FloatArray
) -> FloatArray:  # pragma: no cover - jit
    """(N, 3, n_v) world-axis Jacobians of points ``p_world`` (N, 3) [m] on joints ``joint``:
    ``v_p = v_0 + omega x p`` from the (6, n_v) spatial Jacobian ``J`` in the base frame, masked
    by ``support[joint]`` (the joints that move each point) and rotated to the world by ``wMb``.

    Rounded as the numpy form it replaced: the base-frame point as a BLAS product (a fused
    multiply-add chain from zero, :func:`wholehand.jit.fma`), the rotation as ``einsum`` sums:
    from zero, in index order.
    """
    n, n_v = p_world.shape[0], J.shape[1]
    out = np.empty((n, 3, n_v))
    v = np.empty((3, n_v))
    for i in range(n):
        d0 = p_world[i, 0] - wMb[0, 3]
        d1 = p_world[i, 1] - wMb[1, 3]
        d2 = p_world[i, 2] - wMb[2, 3]
        # p = (p_world - t) @ wRb: the point in the base frame.
        px = fma(d2, wMb[2, 0], fma(d1, wMb[1, 0], fma(d0, wMb[0, 0], 0.0)))
        py = fma(d2, wMb[2, 1], fma(d1, wMb[1, 1], fma(d0, wMb[0, 1], 0.0)))
        pz = fma(d2, wMb[2, 2], fma(d1, wMb[1, 2], fma(d0, wMb[0, 2], 0.0)))
        row = support[joint[i]]
        for k in range(n_v):
            s = row[k]
            v[0, k] = (J[0, k] + J[4, k] * pz - J[5, k] * py) * s
            v[1, k] = (J[1, k] + J[5, k] * px - J[3, k] * pz) * s
            v[2, k] = (J[2, k] + J[3, k] * py - J[4, k] * px) * s
        for a in range(3):
            r0, r1, r2 = wMb[a, 0], wMb[a, 1], wMb[a, 2]
            for k in range(n_v):
                out[i, a, k] = 0.0 + r0 * v[0, k] + r1 * v[1, k] + r2 * v[2, k]
    return out


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def _joint_poses(
    fMw: FloatArray, wMb: FloatArray, bRj: FloatArray, bp_j: FloatArray
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - jit
    """Rotations (J, 3, 3) and positions (J, 3) [m] of the joint frames ``bRj``, ``bp_j`` (base
    frame) in frame f: ``fMb = fMw wMb``, then ``fRj = fRb bRj``, ``fp_j = fRb bp_j + fp_b``.

    Rounded as the numpy form it replaced: ``fMb`` and ``fRb bp_j`` as BLAS products (fused
    multiply-add chains from zero), ``fRb bRj`` as ``einsum`` sums them (from zero, in order).
    """
    fMb = np.empty((4, 4))
    for a in range(4):
        for c in range(4):
            s = 0.0
            for b in range(4):
                s = fma(fMw[a, b], wMb[b, c], s)
            fMb[a, c] = s
    n = bRj.shape[0]
    R = np.empty((n, 3, 3))
    t = np.empty((n, 3))
    for j in range(n):
        for a in range(3):
            r0, r1, r2 = fMb[a, 0], fMb[a, 1], fMb[a, 2]
            for c in range(3):
                R[j, a, c] = 0.0 + r0 * bRj[j, 0, c] + r1 * bRj[j, 1, c] + r2 * bRj[j, 2, c]
            s = fma(bp_j[j, 0], r0, 0.0)
            s = fma(bp_j[j, 1], r1, s)
            t[j, a] = fma(bp_j[j, 2], r2, s) + fMb[a, 3]
    return R, t


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _rotated(
    R: FloatArray, j: int, a: int, x: float, y: float, z: float
) -> float:  # pragma: no cover - jit
    """Component ``a`` of ``R[j] (x, y, z)``, the three products summed as numpy's
    ``einsum("nab,nb->na")`` sums them (two lanes: ``(x0 + x2) + x1``)."""
    return float((R[j, a, 0] * x + R[j, a, 2] * z) + R[j, a, 1] * y)


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def _transform(
    R: FloatArray, t: FloatArray, p_joint: FloatArray, joint: IntArray
) -> FloatArray:  # pragma: no cover - jit
    """(P, 3) points ``R[joint] p_joint + t[joint]`` (rounded as :func:`_rotated`)."""
    out = np.empty((p_joint.shape[0], 3))
    for i in range(p_joint.shape[0]):
        j = joint[i]
        x, y, z = p_joint[i, 0], p_joint[i, 1], p_joint[i, 2]
        for a in range(3):
            out[i, a] = _rotated(R, j, a, x, y, z) + t[j, a]
    return out


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def _to_joint_frames(
    R: FloatArray, t: FloatArray, joint: IntArray, p_world: FloatArray, n_world: FloatArray
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - jit
    """(P, 3) points ``R[j]^T (p - t[j])`` and directions ``R[j]^T n``, ``j = joint[i]``; the
    three products summed as numpy's ``einsum("nba,nb->na")`` sums them (in index order)."""
    p_out = np.empty((p_world.shape[0], 3))
    n_out = np.empty((p_world.shape[0], 3))
    for i in range(p_world.shape[0]):
        j = joint[i]
        x, y, z = p_world[i, 0] - t[j, 0], p_world[i, 1] - t[j, 1], p_world[i, 2] - t[j, 2]
        u, v, w = n_world[i, 0], n_world[i, 1], n_world[i, 2]
        for a in range(3):
            p_out[i, a] = R[j, 0, a] * x + R[j, 1, a] * y + R[j, 2, a] * z
            n_out[i, a] = R[j, 0, a] * u + R[j, 1, a] * v + R[j, 2, a] * w
    return p_out, n_out


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def _from_joint_frames(
    R: FloatArray, t: FloatArray, joint: IntArray, p_joint: FloatArray, n_joint: FloatArray
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - jit
    """(P, 3) points ``R[j] p + t[j]`` and directions ``R[j] n``, ``j = joint[i]`` (rounded as
    :func:`_rotated`)."""
    p_out = np.empty((p_joint.shape[0], 3))
    n_out = np.empty((p_joint.shape[0], 3))
    for i in range(p_joint.shape[0]):
        j = joint[i]
        x, y, z = p_joint[i, 0], p_joint[i, 1], p_joint[i, 2]
        u, v, w = n_joint[i, 0], n_joint[i, 1], n_joint[i, 2]
        for a in range(3):
            p_out[i, a] = _rotated(R, j, a, x, y, z) + t[j, a]
            n_out[i, a] = _rotated(R, j, a, u, v, w)
    return p_out, n_out


def lowest_point(
    hand: HandModel, q: FloatArray, wMb: FloatArray, kinematics: HandKinematics | None = None
) -> float:
    """Lowest world z of the hand's surface samples at ``q``, base at ``wMb`` [m]; updates
    ``kinematics`` (of ``hand``) if given, else a new one."""
    kin = HandKinematics(hand) if kinematics is None else kinematics
    kin.update(q, wMb)
    return float(kin.transform_points(hand.samples.p_joint, hand.samples.joint)[:, 2].min())
