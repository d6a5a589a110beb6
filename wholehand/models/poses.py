"""Pose helpers. Poses are 4x4 homogeneous numpy arrays ``aMb``: the pose of frame b in frame a."""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.errors import ConfigError
from wholehand.jit import CACHE

FloatArray = npt.NDArray[np.float64]


def pose_from_xyz_rpy(xyz: npt.ArrayLike, rpy: npt.ArrayLike) -> FloatArray:
    """(4, 4) pose from a translation [m] and URDF roll-pitch-yaw angles [rad]."""
    M = np.eye(4)
    M[:3, :3] = pin.rpy.rpyToMatrix(np.asarray(rpy, dtype=float))
    M[:3, 3] = np.asarray(xyz, dtype=float)
    return M


_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])


@numba.njit(cache=CACHE, nogil=True)
def is_rigid(M: FloatArray) -> bool:  # pragma: no cover - jit
    """True when the (4, 4) ``M`` is finite, its rotation block orthonormal within 1e-6 with a
    positive determinant, and its last row [0, 0, 0, 1] within 1e-12 (the tolerances of
    :func:`check_pose`, which says what is wrong)."""
    for i in range(4):
        for j in range(4):
            if not np.isfinite(M[i, j]):
                return False
    for i in range(3):
        for j in range(3):
            dot = M[i, 0] * M[j, 0] + M[i, 1] * M[j, 1] + M[i, 2] * M[j, 2]
            if abs(dot - (1.0 if i == j else 0.0)) > 1e-6:
                return False
    det = (
        M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1])
        - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
        + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0])
    )
    if det < 0.0:
        return False
    for j in range(3):
        if abs(M[3, j]) > 1e-12:
            return False
    return bool(abs(M[3, 3] - 1.0) <= 1e-12)


def check_pose(M: npt.ArrayLike, name: str = "pose") -> FloatArray:
    """Validate a (4, 4) homogeneous transform; raise :class:`ConfigError` naming ``name`` if not.

    A valid pose costs one compiled check (:func:`is_rigid`); an invalid one is examined again
    to say what is wrong.
    """
    M = np.asarray(M, dtype=float)
    if M.shape != (4, 4):
        raise ConfigError(f"{name} must be a (4, 4) homogeneous transform, got shape {M.shape}")
    if is_rigid(M):
        return M
    # Rejected: say why.
    if not np.isfinite(M).all():
        raise ConfigError(f"{name} contains NaN or inf: {M.tolist()}")
    if np.abs(M[3] - _LAST_ROW).max() > 1e-12:
        raise ConfigError(f"{name} must have last row [0, 0, 0, 1], got {M[3].tolist()}")
    raise ConfigError(
        f"{name} has a rotation block that is not a proper rotation (orthonormal within 1e-6, "
        f"determinant > 0): {M[:3, :3].tolist()}"
    )


def inverse(M: FloatArray) -> FloatArray:
    """Inverse of a (4, 4) rigid transform."""
    Minv = np.eye(4)
    R = M[:3, :3]
    Minv[:3, :3] = R.T
    Minv[:3, 3] = -R.T @ M[:3, 3]
    return Minv


def rotation_angle(Ra: npt.ArrayLike, Rb: npt.ArrayLike) -> float:
    """Angle of the rotation between two (3, 3) rotations [rad], in [0, pi]."""
    dR = np.asarray(Ra).T @ np.asarray(Rb)
    return float(np.arccos(np.clip(0.5 * (np.trace(dR) - 1.0), -1.0, 1.0)))
