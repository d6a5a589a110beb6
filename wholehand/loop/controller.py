"""One force-regulation cycle: state -> contacts -> Jacobians -> QP -> joint torques."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from wholehand.allocation.base import Allocation, AllocationStatus, Allocator
from wholehand.backends.base import HandObjectState
from wholehand.contacts.base import ContactEstimator, ContactSet
from wholehand.errors import ConfigError
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class CycleResult:
    """Everything one control cycle computed."""

    contacts: ContactSet
    allocation: Allocation
    estimate_time: float
    """Forward kinematics plus contact estimation [s]."""
    cycle_time: float
    """The whole cycle, state in to torque out [s]."""


class ForceRegulationController:
    """The paper's loop body: estimate contacts on every link, allocate forces, map to torques.

    Args:
        hand: the hand model.
        obj: the object model (its centre of mass is the reference point of the grasp matrix).
        estimator: a contact estimator plug-in instance.
        allocator: an allocator plug-in instance.
    """

    def __init__(
        self, hand: HandModel, obj: ObjectModel, estimator: ContactEstimator, allocator: Allocator
    ) -> None:
        self.hand, self.obj = hand, obj
        self.estimator, self.allocator = estimator, allocator
        self.kinematics = HandKinematics(hand)
        self._com_h = np.r_[np.asarray(obj.com, dtype=float), 1.0]
        self._last_tau = np.zeros(hand.nv)
        self.bad_states = 0
        """Cycles whose observation was unusable (their last torque was kept)."""
        self.last_fault = ""
        """Why the latest unusable observation was rejected."""

    def reset(self) -> None:
        """Forget warm starts and the last torque."""
        self.allocator.reset()
        self._last_tau = np.zeros(self.hand.nv)

    def _keep_last_torque(self, start: float, err: ConfigError) -> CycleResult:
        """The paper's safe behaviour for an unusable observation: keep the last torque."""
        self.bad_states += 1
        self.last_fault = str(err)
        hand = self.hand
        contacts = ContactSet.empty(hand.link_actuated, hand.link_fingertip)
        allocation = Allocation(
            f_local=np.zeros((0, 3)),
            f_world=np.zeros((0, 3)),
            tau=self._last_tau.copy(),
            residual_wrench=np.zeros(6),
            status=AllocationStatus.BAD_STATE,
        )
        elapsed = time.perf_counter() - start
        return CycleResult(contacts, allocation, elapsed, elapsed)

    def step(self, state: HandObjectState, wMo: FloatArray | None = None) -> CycleResult:
        """One cycle at a measured state; never raises on a bad observation.

        Args:
            state: the observation (q, base pose, object pose).
            wMo: (4, 4) object pose to use instead of ``state.wMo`` (e.g. a perturbed estimate).

        An observation with NaN or inf joint angles, or a base or object pose that is not a rigid
        transform, yields status ``BAD_STATE`` with the last torque, and counts in
        :attr:`bad_states`.
        """
        start = time.perf_counter()
        wMo = state.wMo if wMo is None else wMo
        try:
            self.kinematics.update(state.q, state.wMb)
            contacts = self.estimator.estimate(self.kinematics, wMo, stamp=state.stamp_object)
        except ConfigError as err:
            return self._keep_last_torque(start, err)
        estimated = time.perf_counter()
        J = self.kinematics.point_jacobians(self.hand.link_joint[contacts.link], contacts.p_world)
        allocation = self.allocator.allocate(contacts, J, (wMo @ self._com_h)[:3])
        self._last_tau = allocation.tau
        end = time.perf_counter()
        return CycleResult(contacts, allocation, estimated - start, end - start)
