"""Non-adaptive baseline: task-space impedance control (paper Sec. IV-A-1).

At grasp initialisation the whole-hand QP of :class:`wholehand_plugins.qp.QPAllocator` is solved
once on the ground-truth simulator contacts. Each contact point i is then fixed on its link
(stored in its parent joint's frame) and given a world target offset along its allocated force,

    x*_i = x_i(q0) + f_i / k,

so that a Cartesian spring of stiffness k at the initial configuration produces exactly f_i.
Every cycle, at the current configuration q,

    tau = sum_i J_i(q)^T k (x*_i - x_i(q))        (commanded joints only),

with the targets fixed in the world: when the object moves, the springs keep pulling toward the
initial contact locations. The backend clips the torque to its limits. No damping is added: the
hand's joint damping in the simulation is the only dissipation, as for the other methods.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from wholehand_plugins.qp import QPAllocator

from wholehand.allocation.base import Allocation
from wholehand.allocation.baselines import FixedAllocationBaseline
from wholehand.contacts.base import ContactSet
from wholehand.errors import ConfigError
from wholehand.models.kinematics import HandKinematics

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

STIFFNESS = 300.0
"""Cartesian stiffness of each contact spring [N/m]. The paper gives no value: at 300 N/m the
few-newton forces of a power grasp put the targets 1-3 cm inside the object, the scale of a
fingertip pad, so the springs neither saturate the 0.2 N*m joints at the start (their torque is
J^T f by construction) nor go slack after millimetres of object motion."""


class ImpedanceBaseline(FixedAllocationBaseline):
    """Per-contact Cartesian springs toward targets fixed at initialisation (status ``HOLD``).

    Args:
        stiffness: Cartesian stiffness k of every contact spring [N/m], > 0.
        **qp_params: parameters of the initial :class:`QPAllocator` (``mu``, ``f_n_min``,
            ``tau_max``, ``eps_margin``, ``consistency``, ``actuated_dofs``, ``solver``, ...).
    """

    def __init__(self, stiffness: float = STIFFNESS, **qp_params: Any) -> None:
        if not (isinstance(stiffness, int | float) and 0.0 < stiffness < np.inf):
            raise ConfigError(
                f"ImpedanceBaseline: stiffness={stiffness!r} is invalid; it must be a finite "
                "number > 0 [N/m]"
            )
        super().__init__(QPAllocator(**qp_params), qp_params.get("actuated_dofs"))
        self.stiffness = float(stiffness)
        self.p_joint: FloatArray = np.zeros((0, 3))
        """(N, 3) contact points in their parent joint's frame [m]."""
        self.joint: IntArray = np.zeros(0, dtype=np.intp)
        """(N,) parent joint of each contact point."""
        self.x_target: FloatArray = np.zeros((0, 3))
        """(N, 3) spring targets, world frame [m]."""

    def _initialise(
        self,
        contacts_gt: ContactSet,
        J_gt: FloatArray,
        allocation: Allocation,
        kinematics: HandKinematics,
    ) -> None:
        self.joint = kinematics.hand.link_joint[contacts_gt.link].astype(np.intp)
        R, t = kinematics.joint_poses_in(np.eye(4))  # joint frames in the world
        # p_joint = R^T (p_world - t), per contact.
        self.p_joint = np.einsum("nba,nb->na", R[self.joint], contacts_gt.p_world - t[self.joint])
        self.x_target = contacts_gt.p_world + allocation.f_world / self.stiffness

    def spring_forces(self, kinematics: HandKinematics) -> tuple[FloatArray, FloatArray]:
        """Contact points (N, 3) [m] and spring forces k (x* - x) (N, 3) [N], world, at the
        configuration of ``kinematics``."""
        x = kinematics.transform_points(self.p_joint, self.joint)
        return x, self.stiffness * (self.x_target - x)

    def command(self, kinematics: HandKinematics) -> FloatArray:
        """``sum_i J_i(q)^T k (x*_i - x_i(q))`` at the configuration of ``kinematics`` [N*m]."""
        kin = kinematics
        n_v = kin.hand.n_actuation
        if self.joint.size == 0:
            return np.zeros(n_v)
        x, f = self.spring_forces(kin)
        J = kin.actuation_jacobians(self.joint, x)
        tau = np.einsum("nak,na->k", J, f)
        tau[~self.actuated_mask(n_v)] = 0.0
        return tau


__all__ = ["STIFFNESS", "ImpedanceBaseline"]
