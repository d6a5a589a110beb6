"""The backend interface: where joint torques go and states come from (simulation or hardware)."""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class HandObjectState:
    """One observation of the hand and the tracked object.

    Poses are 4x4 homogeneous transforms ``aMb`` (pose of frame b in frame a) throughout wholehand.
    """

    q: FloatArray
    """(n_q,) hand joint positions [rad or m], in the order of the hand's Pinocchio model."""
    dq: FloatArray
    """(n_v,) hand joint velocities [rad/s or m/s]."""
    wMb: FloatArray
    """(4, 4) pose of the hand base (root link) in the world."""
    wMo: FloatArray
    """(4, 4) pose of the object frame in the world."""
    stamp_q: float
    """Time at which q and dq were measured [s]."""
    stamp_object: float
    """Time at which the object pose was measured [s]."""


class Backend(abc.ABC):
    """A hand-object system that can be read, commanded and advanced in time.

    Registered in the ``wholehand.backends`` entry-point group.
    """

    @abc.abstractmethod
    def read_state(self) -> HandObjectState:
        """The latest observation."""

    @abc.abstractmethod
    def apply_torques(self, tau: FloatArray) -> None:
        """Command (n_v,) joint torques [N*m], held until the next command."""

    @abc.abstractmethod
    def step(self, duration: float) -> None:
        """Advance time by ``duration`` seconds (simulation) or wait for it (hardware)."""

    @property
    @abc.abstractmethod
    def time(self) -> float:
        """Current time of the backend [s]."""


class PerturbableBackend(Backend):
    """A backend that can push the object with an external wrench (simulation)."""

    @abc.abstractmethod
    def apply_object_wrench(self, force_world: FloatArray, torque_world: FloatArray) -> None:
        """Apply an external force [N] and torque [N*m] at the object's centre of mass, world
        axes, held until changed."""

    @abc.abstractmethod
    def set_object_spring(
        self,
        wMo_target: FloatArray | None,
        stiffness: tuple[float, float] = (0.0, 0.0),
        damping: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        """Pull the object toward a target pose with a spring-damper evaluated at every
        simulation step (stable where a wrench held over a control period would not be).

        Args:
            wMo_target: (4, 4) target object pose; None removes the spring.
            stiffness: translational [N/m] (on the centre of mass) and rotational [N*m/rad].
            damping: translational [N*s/m] and rotational [N*m*s/rad].
        """
