"""4x4 poses to and from MuJoCo's position + quaternion (w, x, y, z) form."""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

_IDENTITY = np.eye(4)
_IDENTITY.setflags(write=False)


def mujoco_quat(M: FloatArray) -> FloatArray:
    """(4,) unit quaternion (w, x, y, z) of the rotation of the (4, 4) pose ``M``."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(np.asarray(M)[:3, :3]).ravel())
    return quat


def pose_from_mujoco(pos: npt.ArrayLike, quat: npt.ArrayLike) -> FloatArray:
    """(4, 4) pose from a position (3,) [m] and a quaternion (w, x, y, z)."""
    M = _IDENTITY.copy()  # np.eye costs several times more, once per pose in every cycle
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, np.asarray(quat, dtype=float))
    M[:3, :3] = R.reshape(3, 3)
    M[:3, 3] = pos
    return M


def set_spec_pose(element: Any, M: FloatArray) -> None:
    """Set an MjSpec body's (or frame's) ``pos`` and ``quat`` from the pose ``M`` (4, 4)."""
    element.pos = M[:3, 3].tolist()
    element.quat = mujoco_quat(M).tolist()
