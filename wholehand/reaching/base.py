"""The reacher interface: joint velocities that bring the hand to a grasp (paper Sec. III-D)."""

from __future__ import annotations

import abc

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


class Reacher(abc.ABC):
    """Computes a joint velocity command toward target fingertip and palm poses.

    Registered in the ``wholehand.reachers`` entry-point group.
    """

    @abc.abstractmethod
    def velocity(
        self, q: FloatArray, wMb: FloatArray, targets_world: dict[str, FloatArray], dt: float
    ) -> FloatArray:
        """(n_v,) joint velocity [rad/s] for one control period ``dt`` [s].

        Args:
            q: (n_q,) current joint positions.
            wMb: (4, 4) pose of the hand base in the world.
            targets_world: link name -> (4, 4) target pose of that link in the world.
            dt: control period [s].
        """
