"""Force allocations and the allocator interface (paper Sec. III-C)."""

from __future__ import annotations

import abc
import enum
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from wholehand.contacts.base import ContactSet

FloatArray = npt.NDArray[np.float64]


class AllocationStatus(str, enum.Enum):
    """Outcome of one allocation."""

    OK = "ok"
    """The QP was solved; the torque is new."""
    EMPTY = "empty"
    """No contacts: zero torque."""
    NO_ACTUATED_CONTACT = "no_actuated_contact"
    """Contacts exist but none is on an actuated link: zero torque."""
    INFEASIBLE = "infeasible"
    """The QP has no solution; the last feasible torque is kept."""
    SOLVER_FAILED = "solver_failed"
    """The solver failed or returned garbage; the last feasible torque is kept."""
    HOLD = "hold"
    """A non-adaptive allocator applies its stored command."""
    BAD_STATE = "bad_state"
    """The observation was unusable (NaN, inf, not a pose); the last torque is kept."""


@dataclass(frozen=True)
class Allocation:
    """Result of one force allocation."""

    f_local: FloatArray
    """(N, 3) contact forces [f_n, f_t1, f_t2] in each contact's local frame [N]."""
    f_world: FloatArray
    """(N, 3) the same forces, applied by the hand on the object, in the world frame [N]."""
    tau: FloatArray
    """(n_v,) joint torques commanded to the hand's joints [N*m]."""
    residual_wrench: FloatArray
    """(6,) net contact wrench on the object [force N, torque N*m] about its centre of mass,
    world axes."""
    status: AllocationStatus
    """Why the torque is what it is."""
    solve_time: float = 0.0
    """Wall time of the QP solve [s]."""
    solver: str = ""
    """Name of the QP solver that produced the result."""

    @property
    def ok(self) -> bool:
        """True when this cycle produced a fresh, feasible torque."""
        return self.status is AllocationStatus.OK


class Allocator(abc.ABC):
    """Turns a :class:`ContactSet` and contact Jacobians into an :class:`Allocation`.

    Registered in the ``wholehand.allocators`` entry-point group. Inside the control loop an
    allocator never raises on a failed solve: it keeps the last feasible torque and says so in
    :attr:`Allocation.status`.
    """

    @abc.abstractmethod
    def allocate(
        self, contacts: ContactSet, J_world: FloatArray, p_com_world: FloatArray
    ) -> Allocation:
        """Contact forces and joint torques for the current contacts.

        Args:
            contacts: The contacts of this cycle (N of them).
            J_world: (N, 3, n_v) point Jacobians of the hand at the contact points: linear
                velocity of each contact point, world axes, per joint velocity.
            p_com_world: (3,) object centre of mass in the world [m].
        """

    def reset(self) -> None:  # noqa: B027 - an optional hook, stateless allocators keep it
        """Forget state carried between cycles (warm start, last feasible torque)."""
