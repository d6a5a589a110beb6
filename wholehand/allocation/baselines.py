"""Non-adaptive baselines of the paper's perturbation study (Sec. IV-A-1).

Both baselines follow the usual execution pipeline of grasp synthesis: contact forces are
allocated ONCE, at grasp initialisation, from the ground-truth simulator contacts (the same QP as
the adaptive controller, run on the ground-truth contact set), and never again. They differ only
in how they apply those forces afterwards (see ``wholehand_plugins.feedforward`` and
``wholehand_plugins.impedance``).

Life cycle: on the first cycle of force regulation the stage calls
:meth:`FixedAllocationBaseline.start` with the cycle's context, whose ``ground_truth()`` gives
the simulator's contacts (mapped into the object pose the controller sees); the baseline
allocates once there (:meth:`~FixedAllocationBaseline.initialise`). From then on
:meth:`~FixedAllocationBaseline.allocate` is called every cycle as for any allocator; the
baseline ignores the estimated contacts and applies its law at the configuration of the
``kinematics`` it is given.
"""

from __future__ import annotations

import abc
from typing import ClassVar, cast

import numpy as np
import numpy.typing as npt

from wholehand.allocation.base import Allocation, AllocationStatus, Allocator, StartContext
from wholehand.contacts.base import ContactSet
from wholehand.errors import ConfigError
from wholehand.models.kinematics import HandKinematics

FloatArray = npt.NDArray[np.float64]


class FixedAllocationBaseline(Allocator):
    """An allocator that allocates once from ground-truth contacts, then applies a stored law.

    Args:
        allocator: the force-allocation QP run once at initialisation (e.g. ``QPAllocator``).
        actuated_dofs: commanded joints, an (n_v,) boolean mask or joint indices; None: all.
            Torques on other joints are zero.

    Attributes:
        initial: the allocation computed at initialisation (None before).
        contacts_gt: the ground-truth contact set it was computed on (None before).
        J_gt: (N, 3, n_v) point Jacobians of those contacts at the initial configuration.
    """

    needs_ground_truth: ClassVar[bool] = True

    def __init__(self, allocator: Allocator, actuated_dofs: npt.ArrayLike | None = None) -> None:
        self.allocator = allocator
        self._actuated = None if actuated_dofs is None else np.asarray(actuated_dofs)
        self.initial: Allocation | None = None
        self.contacts_gt: ContactSet | None = None
        self.J_gt: FloatArray | None = None

    # --------------------------------------------------------------------------------------------
    def start(self, context: StartContext) -> None:
        """Allocate once on the ground-truth contacts at this cycle's configuration.

        Raises:
            ConfigError: the context has no ground truth (the backend offers none).
        """
        if context.ground_truth is None:
            raise ConfigError(
                f"{type(self).__name__} needs ground-truth contacts at initialisation; the "
                "backend has no ground_truth_contacts() (use a simulation backend)"
            )
        wMo = context.obs.wMo
        assert wMo is not None
        p_com = wMo[:3, :3] @ context.obj.com + wMo[:3, 3]
        self.initialise(context.ground_truth(), context.kinematics, p_com)

    def initialise(
        self, contacts_gt: ContactSet, kinematics: HandKinematics, p_com_world: FloatArray
    ) -> Allocation:
        """Allocate forces once on the ground-truth contacts at the current configuration.

        Args:
            contacts_gt: ground-truth contacts at grasp initialisation (world frame).
            kinematics: the hand at the initial state (read now, not kept).
            p_com_world: (3,) object centre of mass in the world [m].

        Returns:
            The initial allocation. When it gave no fresh torque (no contact, infeasible QP;
            see :attr:`~wholehand.allocation.base.Allocation.fresh`) the baseline applies zero
            forces: it has nothing else to hold.
        """
        hand = kinematics.hand
        J = kinematics.actuation_jacobians(hand.link_joint[contacts_gt.link], contacts_gt.p_world)
        self.allocator.reset()
        allocation = self.allocator.allocate(contacts_gt, J, np.asarray(p_com_world, dtype=float))
        if not allocation.fresh:
            n = len(contacts_gt)
            allocation = Allocation(
                f_local=np.zeros((n, 3)),
                f_world=np.zeros((n, 3)),
                tau=np.zeros(hand.n_actuation),
                residual_wrench=np.zeros(6),
                status=allocation.status,
                solve_time=allocation.solve_time,
                solver=allocation.solver,
            )
        self.initial, self.contacts_gt, self.J_gt = allocation, contacts_gt, J
        self._initialise(contacts_gt, J, allocation, kinematics)
        return allocation

    @abc.abstractmethod
    def _initialise(
        self,
        contacts_gt: ContactSet,
        J_gt: FloatArray,
        allocation: Allocation,
        kinematics: HandKinematics,
    ) -> None:
        """Store what the control law needs (called once by :meth:`initialise`)."""

    @abc.abstractmethod
    def command(self, kinematics: HandKinematics) -> FloatArray:
        """(n_actuation,) torques of this cycle [N*m] (per joint, or per actuator for a coupled
        hand), from the stored allocation and the current configuration ``kinematics``."""

    # --------------------------------------------------------------------------------------------
    @property
    def initialised(self) -> bool:
        return self.initial is not None

    def actuated_mask(self, n_v: int) -> npt.NDArray[np.bool_]:
        """(n_v,) True for the commanded joints."""
        if self._actuated is None:
            return np.ones(n_v, dtype=bool)
        if self._actuated.dtype == bool:
            if self._actuated.shape != (n_v,):
                raise ConfigError(
                    f"{type(self).__name__}: actuated_dofs mask has shape {self._actuated.shape}, "
                    f"the hand has n_v={n_v} joints"
                )
            return cast(npt.NDArray[np.bool_], self._actuated.copy())
        mask = np.zeros(n_v, dtype=bool)
        mask[self._actuated.astype(np.intp)] = True
        return mask

    def allocate(
        self,
        contacts: ContactSet,
        J_world: FloatArray,
        p_com_world: FloatArray,
        kinematics: HandKinematics | None = None,
    ) -> Allocation:
        """The stored law's torque at ``kinematics``; the estimated ``contacts`` are ignored
        (status ``HOLD``).

        The per-contact arrays have one zero row per estimated contact (the baseline assigns
        no force to them); the residual wrench is that of the initial allocation.

        Raises:
            ConfigError: :meth:`initialise` was not called first, or no ``kinematics``.
        """
        if self.initial is None:
            raise ConfigError(
                f"{type(self).__name__}: allocate() before initialise(); a non-adaptive baseline "
                "needs the ground-truth contacts at grasp initialisation (run it through "
                "wholehand.trials.trial.run_trial, or call initialise() yourself)"
            )
        if kinematics is None:
            raise ConfigError(
                f"{type(self).__name__}.allocate needs the hand kinematics at the current q"
            )
        n = len(contacts)
        return Allocation(
            f_local=np.zeros((n, 3)),
            f_world=np.zeros((n, 3)),
            tau=self.command(kinematics),
            residual_wrench=self.initial.residual_wrench.copy(),
            status=AllocationStatus.HOLD,
            solve_time=0.0,
            solver=self.initial.solver,
        )

    def reset(self) -> None:
        """Keep the initial allocation (a baseline never re-allocates); reset the inner QP."""
        self.allocator.reset()


__all__ = ["FixedAllocationBaseline"]
