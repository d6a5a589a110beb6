"""Force allocations and the allocator interface (paper Sec. III-C)."""

from __future__ import annotations

import abc
import enum
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np
import numpy.typing as npt

from wholehand import defaults
from wholehand.contacts.base import ContactSet
from wholehand.errors import ConfigError

if TYPE_CHECKING:
    from wholehand.backends.observation import Observation
    from wholehand.models.hand import HandModel
    from wholehand.models.kinematics import HandKinematics
    from wholehand.models.objects import ObjectModel

FloatArray = npt.NDArray[np.float64]


class StartContext(Protocol):
    """What :meth:`Allocator.start` may read of the first regulated cycle (the loop passes its
    :class:`~wholehand.loop.stage.CycleContext`)."""

    obs: Observation
    """The observation of the cycle."""
    obj: ObjectModel
    ground_truth: Callable[[], ContactSet] | None
    """The simulator's contacts in the observed object pose (None without ground truth)."""

    @property
    def kinematics(self) -> HandKinematics:
        """The hand at the cycle's joint reading."""
        ...


class AllocationStatus(str, enum.Enum):
    """Outcome of one allocation."""

    OK = "ok"
    """The QP was solved and its forces balance the object (:attr:`Allocation.balanced`); the
    torque is new."""
    UNBALANCED = "unbalanced"
    """The QP was solved within its limits but its forces do not balance the object: the
    residual wrench is out of tolerance (the limits, the friction cones or the minimum squeeze
    leave no balancing forces), or there is no contact force at all. The torque is new and is
    applied: it is the least residual the hand can exert within its limits."""
    INACCURATE = "inaccurate"
    """The solver's answer violates a constraint (a torque limit, a friction cone, the minimum
    squeeze, actuation consistency) by more than the allocator's relative tolerance: no torque
    (the loop keeps the last feasible one)."""
    EMPTY = "empty"
    """No contacts: zero torque."""
    NO_ACTUATED_CONTACT = "no_actuated_contact"
    """Contacts exist but none is on an actuated link: zero torque."""
    INFEASIBLE = "infeasible"
    """The QP has no solution: no torque (the loop keeps the last feasible one)."""
    SOLVER_FAILED = "solver_failed"
    """The solver failed or returned garbage: no torque (the loop keeps the last feasible one)."""
    HOLD = "hold"
    """A non-adaptive allocator applies its stored command."""
    DEADLINE = "deadline"
    """The solve ran past its deadline before it was done: no torque (the loop keeps the last
    feasible one)."""


FRESH_STATUSES: frozenset[AllocationStatus] = frozenset(
    {AllocationStatus.OK, AllocationStatus.UNBALANCED}
)
"""Statuses of allocations that produced a fresh torque within the limits."""


@dataclass(frozen=True)
class Allocation:
    """Result of one force allocation."""

    f_local: FloatArray
    """(N, 3) contact forces [f_n, f_t1, f_t2] in each contact's local frame [N]."""
    f_world: FloatArray
    """(N, 3) the same forces, applied by the hand on the object, in the world frame [N]."""
    tau: FloatArray | None
    """(n_v,) joint torques commanded to the hand's joints [N*m]; None when the allocation
    produced none (``INFEASIBLE``, ``SOLVER_FAILED``, ``INACCURATE``, ``DEADLINE``): the caller
    keeps its last feasible torque."""
    residual_wrench: FloatArray
    """(6,) net contact wrench on the object [force N, torque N*m] about its centre of mass,
    world axes."""
    status: AllocationStatus
    """Why the torque is what it is."""
    solve_time: float = 0.0
    """Wall time of the QP solve [s]."""
    solver_time: float = 0.0
    """The part of :attr:`solve_time` spent inside the QP solver's calls (all screening rounds)
    [s]; the rest is building the problems and the allocator's own work. 0 for allocators
    without a QP."""
    solver: str = ""
    """Name of the QP solver that produced the result."""

    @property
    def ok(self) -> bool:
        """True when this cycle produced a fresh, feasible torque whose forces balance the
        object (status ``OK``)."""
        return self.status is AllocationStatus.OK

    @property
    def fresh(self) -> bool:
        """True when this cycle produced a fresh torque within the limits, balancing or not
        (status ``OK`` or ``UNBALANCED``)."""
        return self.status in FRESH_STATUSES

    @property
    def balanced(self) -> bool:
        """True when the allocated forces balance the object: some contact force is non-zero,
        and the residual force and torque are within
        :data:`~wholehand.defaults.BALANCE_TOL_FORCE` and
        :data:`~wholehand.defaults.BALANCE_TOL_TORQUE`. The QP allocator gives a solved
        allocation that does not balance the status ``UNBALANCED``."""
        return is_balanced(self.residual_wrench, self.f_world)


def is_balanced(residual_wrench: npt.ArrayLike, f_world: npt.ArrayLike) -> bool:
    """See :attr:`Allocation.balanced` (for a recorded residual (6,) [N, N*m] and contact
    forces (N, 3) [N])."""
    w = np.asarray(residual_wrench, dtype=float)
    return bool(
        np.abs(np.asarray(f_world, dtype=float)).sum() > 0.0
        and np.linalg.norm(w[:3]) <= defaults.BALANCE_TOL_FORCE
        and np.linalg.norm(w[3:]) <= defaults.BALANCE_TOL_TORQUE
    )


def checked_jacobians(J_world: npt.ArrayLike, n_contacts: int, owner: str) -> FloatArray:
    """``J_world`` as a float64 array, checked to be (n_contacts, 3, n_v): the stacked point
    Jacobians of the contacts, world axes; anything else raises ConfigError naming ``owner``."""
    J = np.asarray(J_world, dtype=np.float64)
    if J.ndim != 3 or J.shape[:2] != (n_contacts, 3):
        raise ConfigError(
            f"{owner}: J_world has shape {J.shape}, expected ({n_contacts}, 3, n_v) for the "
            f"{n_contacts} contacts of the set"
        )
    return J


def hand_keywords(hand: HandModel) -> dict[str, Any]:
    """Constructor keywords the trial set-up derives from the hand and passes to an allocator
    whose constructor accepts them: ``tau_max`` (torque limit per coordinate [N*m], ``inf``
    where none) and ``actuated_dofs`` (bool, True for the coordinates the allocator commands),
    both (n_actuation,): per joint, or per actuator for a coupled hand (the Jacobians are then
    ``J C``, see :meth:`~wholehand.models.kinematics.HandKinematics.actuation_jacobians`); and
    ``f_n_min``, the minimum squeeze [N], where hand.toml sets one (``[control] squeeze``)."""
    squeeze = {} if hand.config.squeeze is None else {"f_n_min": hand.config.squeeze}
    if hand.coupled:
        return {
            "tau_max": hand.tau_max[hand.actuated_dofs].copy(),
            "actuated_dofs": np.ones(hand.n_actuation, dtype=bool),
            **squeeze,
        }
    return {
        "tau_max": hand.tau_max.copy(),
        "actuated_dofs": hand.actuated_dofs.copy(),
        **squeeze,
    }


class Allocator(abc.ABC):
    """Turns a :class:`ContactSet` and contact Jacobians into an :class:`Allocation`.

    Registered in the ``wholehand.allocators`` entry-point group. The contract:

    - Construction: keyword arguments only: the user's parameters, plus those hand keywords
      (:func:`hand_keywords`) that the constructor accepts (by name, or through ``**params``).
    - :meth:`start` (optional): called on the first cycle of force regulation with the cycle's
      context, e.g. to allocate once from ground-truth contacts. A class that needs them sets
      :attr:`needs_ground_truth`, and the set-up refuses a backend without them.
    - :meth:`allocate`: every cycle. Inside the control loop it never raises on a failed
      solve: it returns no torque (``tau=None``) and says why in :attr:`Allocation.status`; the
      loop keeps the last feasible torque.
    - :meth:`reset` (optional): forget what is carried between cycles (warm starts).
    - Known external wrench (optional): a class that sets :attr:`supports_external_wrench`
      also takes ``allocate(..., external_wrench=w)``, w (6,) the wrench on the object about
      its COM, world axes [N, N*m] (e.g. its weight), and balances ``G f + w`` instead of
      ``G f``.
    - Torque bias (optional): a class that sets :attr:`supports_tau_bias` also takes
      ``allocate(..., tau_bias=b)``, b (n_v,) the torque the joints command besides the contact
      forces [N*m] (the hand links' weight): it keeps ``b + tau`` within the torque limits. The
      returned ``tau`` stays the contact forces' part; the caller adds ``b``.
    """

    needs_ground_truth: ClassVar[bool] = False
    """True for allocators whose :meth:`start` reads ``context.ground_truth()``."""
    supports_external_wrench: ClassVar[bool] = False
    """True for allocators whose :meth:`allocate` takes ``external_wrench``."""
    supports_tau_bias: ClassVar[bool] = False
    """True for allocators whose :meth:`allocate` takes ``tau_bias``."""

    def start(self, context: StartContext) -> None:  # noqa: B027 - an optional hook
        """Called on the first cycle of force regulation, before the first :meth:`allocate`."""

    @abc.abstractmethod
    def allocate(
        self,
        contacts: ContactSet,
        J_world: FloatArray,
        p_com_world: FloatArray,
        kinematics: HandKinematics | None = None,
    ) -> Allocation:
        """Contact forces and joint torques for the current contacts.

        Args:
            contacts: The contacts of this cycle (N of them).
            J_world: (N, 3, n_v) point Jacobians of the hand at the contact points: linear
                velocity of each contact point, world axes, per joint velocity (per actuator
                velocity for a coupled hand: ``n_v`` is then the number of actuators, and the
                torques are actuator torques).
            p_com_world: (3,) object centre of mass in the world [m].
            kinematics: the hand at the configuration of ``J_world`` (the loop always passes
                it; only laws that depend on the configuration read it). Read it during the
                call; never keep it.
        """

    def reset(self) -> None:  # noqa: B027 - an optional hook, stateless allocators keep it
        """Forget state carried between cycles (warm start)."""
