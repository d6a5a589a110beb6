"""Non-adaptive baseline: feedforward torque control (paper Sec. IV-A-1).

At grasp initialisation the whole-hand QP of :class:`wholehand_plugins.qp.QPAllocator` is solved
once on the ground-truth simulator contacts; the forces are mapped to joint torques through the
contact Jacobians at the initial configuration, ``tau = J_gt^T f`` (commanded joints only), and
these torques are held for the rest of the trial, whatever the object does.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from wholehand_plugins.qp import QPAllocator

from wholehand.allocation.base import Allocation
from wholehand.allocation.baselines import FixedAllocationBaseline
from wholehand.contacts.base import ContactSet
from wholehand.models.kinematics import HandKinematics

FloatArray = npt.NDArray[np.float64]


class FeedforwardBaseline(FixedAllocationBaseline):
    """Hold ``tau = J_gt^T f`` from the initial ground-truth allocation (status ``HOLD``).

    Args:
        **qp_params: parameters of the initial :class:`QPAllocator` (``mu``, ``f_n_min``,
            ``tau_max``, ``eps_margin``, ``consistency``, ``actuated_dofs``, ``solver``, ...).
    """

    def __init__(self, **qp_params: Any) -> None:
        super().__init__(QPAllocator(**qp_params), qp_params.get("actuated_dofs"))
        self._tau: FloatArray | None = None

    def _initialise(
        self,
        contacts_gt: ContactSet,
        J_gt: FloatArray,
        allocation: Allocation,
        kinematics: HandKinematics,
    ) -> None:
        n_v = J_gt.shape[2] if J_gt.ndim == 3 else kinematics.hand.n_actuation
        tau = (
            np.einsum("nak,na->k", J_gt, allocation.f_world) if len(contacts_gt) else np.zeros(n_v)
        )
        tau[~self.actuated_mask(n_v)] = 0.0
        self._tau = tau

    def command(self, kinematics: HandKinematics) -> FloatArray:
        """The torque computed at initialisation (a copy) [N*m], whatever the configuration."""
        assert self._tau is not None
        return self._tau.copy()


__all__ = ["FeedforwardBaseline"]
