"""Pose helpers. Poses are 4x4 homogeneous numpy arrays ``aMb``: the pose of frame b in frame a."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.errors import ConfigError

FloatArray = npt.NDArray[np.float64]


def pose_from_xyz_rpy(xyz: npt.ArrayLike, rpy: npt.ArrayLike) -> FloatArray:
    """(4, 4) pose from a translation [m] and URDF roll-pitch-yaw angles [rad]."""
    M = np.eye(4)
    M[:3, :3] = pin.rpy.rpyToMatrix(np.asarray(rpy, dtype=float))
    M[:3, 3] = np.asarray(xyz, dtype=float)
    return M


_I3 = np.eye(3)
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])


def check_pose(M: npt.ArrayLike, name: str = "pose") -> FloatArray:
    """Validate a (4, 4) homogeneous transform; raise :class:`ConfigError` naming ``name`` if not.

    Cheap enough for the control loop (a few microseconds).
    """
    M = np.asarray(M, dtype=float)
    if M.shape != (4, 4):
        raise ConfigError(f"{name} must be a (4, 4) homogeneous transform, got shape {M.shape}")
    if not np.isfinite(M).all():
        raise ConfigError(f"{name} contains NaN or inf: {M.tolist()}")
    R = M[:3, :3]
    a, b, c, d, e, f, g, h, i = R.ravel().tolist()
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if np.abs(R @ R.T - _I3).max() > 1e-6 or det < 0.0:
        raise ConfigError(
            f"{name} has a rotation block that is not a proper rotation: {R.tolist()}"
        )
    if np.abs(M[3] - _LAST_ROW).max() > 1e-12:
        raise ConfigError(f"{name} must have last row [0, 0, 0, 1], got {M[3].tolist()}")
    return M


def inverse(M: FloatArray) -> FloatArray:
    """Inverse of a (4, 4) rigid transform."""
    Minv = np.eye(4)
    R = M[:3, :3]
    Minv[:3, :3] = R.T
    Minv[:3, 3] = -R.T @ M[:3, 3]
    return Minv
