"""Ablation of the paper's whole-hand allocation: the same QP on fingertip contacts only.

The contacts are restricted to the distal (fingertip) links (``ContactSet.fingertip``) before the
QP of :class:`wholehand_plugins.qp.QPAllocator` is built; every other contact gets zero force.
The returned arrays keep one row per contact of the input set.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from wholehand_plugins.qp import QPAllocator

from wholehand.allocation.base import Allocation, checked_jacobians
from wholehand.contacts.base import ContactSet
from wholehand.models.kinematics import HandKinematics

FloatArray = npt.NDArray[np.float64]


class FingertipOnlyAllocator(QPAllocator):
    """Force-allocation QP restricted to fingertip contacts (paper ablation)."""

    def allocate(
        self,
        contacts: ContactSet,
        J_world: FloatArray,
        p_com_world: FloatArray,
        kinematics: HandKinematics | None = None,
        *,
        external_wrench: FloatArray | None = None,
        tau_bias: FloatArray | None = None,
    ) -> Allocation:
        """Allocate over ``contacts.select(contacts.fingertip)``; see :meth:`QPAllocator.allocate`.

        An input set without fingertip contacts gives status ``EMPTY``.
        """
        n = len(contacts)
        J_world = checked_jacobians(J_world, n, type(self).__name__)
        mask = contacts.fingertip
        extra = {"external_wrench": external_wrench, "tau_bias": tau_bias}
        if mask.all():
            return super().allocate(contacts, J_world, p_com_world, **extra)
        sub = super().allocate(contacts.select(mask), J_world[mask], p_com_world, **extra)
        f_local = np.zeros((n, 3))
        f_world = np.zeros((n, 3))
        f_local[mask] = sub.f_local
        f_world[mask] = sub.f_world
        return Allocation(
            f_local=f_local,
            f_world=f_world,
            tau=sub.tau,
            residual_wrench=sub.residual_wrench,
            status=sub.status,
            solve_time=sub.solve_time,
            solver=sub.solver,
        )


__all__ = ["FingertipOnlyAllocator"]
