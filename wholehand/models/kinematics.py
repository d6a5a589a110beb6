"""Per-cycle hand kinematics: one forward pass, batched point transforms, point Jacobians.

Frames: ``b`` is the hand base (the URDF root, Pinocchio's "world" of the hand model), ``w`` the
world, ``j`` a joint frame. Pinocchio runs in the base frame; results are mapped to the world
with the mount pose ``wMb``.
"""

from __future__ import annotations

from typing import cast

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.errors import ConfigError
from wholehand.models.hand import HandModel
from wholehand.models.poses import check_pose

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


class HandKinematics:
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
        self.update(self.q, self.wMb)

    def update(self, q: npt.ArrayLike, wMb: FloatArray | None = None) -> None:
        """Run forward kinematics at joint positions ``q`` (n_q,) with base pose ``wMb`` (4, 4)."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self.model.nq,):
            raise ConfigError(
                f"HandKinematics.update: q has shape {q.shape}, hand {self.hand.name!r} "
                f"needs ({self.model.nq},)"
            )
        if not np.all(np.isfinite(q)):
            raise ConfigError(f"HandKinematics.update: q contains NaN or inf: {q.tolist()}")
        if wMb is not None:
            self.wMb = check_pose(wMb, "wMb (hand base pose)")
        self.q = q.copy()
        self.q.setflags(write=False)
        pin.forwardKinematics(self.model, self.data, self.q)
        # One 4x4 per joint out of Pinocchio (each access crosses into Python), then split.
        placements = np.array([oMi.homogeneous for oMi in self.data.oMi])
        self.bRj[:] = placements[:, :3, :3]
        self.bp_j[:] = placements[:, :3, 3]
        self._jacobians_fresh = False

    def joint_poses_in(self, fMw: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Rotations (J, 3, 3) and translations (J, 3) of every joint frame in frame f.

        Args:
            fMw: (4, 4) pose of the world in frame f (e.g. ``oMw`` for the object frame).
        """
        fMb = fMw @ self.wMb
        R = np.einsum("ab,jbc->jac", fMb[:3, :3], self.bRj)
        t = self.bp_j @ fMb[:3, :3].T + fMb[:3, 3]
        return R, t

    def transform_points(
        self, p_joint: FloatArray, joint: IntArray, fMw: FloatArray | None = None
    ) -> FloatArray:
        """Points given in their joint frames, moved to frame f (world if ``fMw`` is None).

        Args:
            p_joint: (P, 3) points, each in the frame of joint ``joint[i]`` [m].
            joint: (P,) joint index of each point.
            fMw: (4, 4) pose of the world in the target frame.
        """
        R, t = self.joint_poses_in(np.eye(4) if fMw is None else fMw)
        return cast(FloatArray, np.einsum("pab,pb->pa", R[joint], p_joint) + t[joint])

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
        J = self.data.J  # (6, n_v) spatial Jacobian in the base frame (Pinocchio WORLD)
        wRb = self.wMb[:3, :3]
        p = (p_world - self.wMb[:3, 3]) @ wRb  # points in the base frame
        px, py, pz = p[:, 0:1], p[:, 1:2], p[:, 2:3]
        wx, wy, wz = J[3], J[4], J[5]
        # v_p = v_0 + omega x p in the base frame, restricted to the joints that move the point.
        v = np.empty((p.shape[0], 3, J.shape[1]))
        v[:, 0] = J[0] + wy * pz - wz * py
        v[:, 1] = J[1] + wz * px - wx * pz
        v[:, 2] = J[2] + wx * py - wy * px
        v *= self._support[joint][:, None, :]
        return cast(FloatArray, np.einsum("ab,nbk->nak", wRb, v))

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
