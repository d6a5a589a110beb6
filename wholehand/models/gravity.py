"""Joint torques that hold a hand (or an arm-hand assembly) against gravity (Pinocchio)."""

from __future__ import annotations

from typing import cast

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.models.hand import HandModel

FloatArray = npt.NDArray[np.float64]

GRAVITY_WORLD: tuple[float, float, float] = (0.0, 0.0, -9.81)
"""Gravity in the world frame [m/s^2]."""


class GravityCompensation:
    """``g(q)``: the joint torques [N*m] that balance the links' weights at rest.

    Works on a private copy of the hand's Pinocchio model, whose gravity is set in the base
    frame from the base pose at each call (the base of a hand on a floating wrist turns).

    Args:
        hand: the hand or assembly.
        g_world: gravity in the world frame [m/s^2].
    """

    def __init__(self, hand: HandModel, g_world: tuple[float, float, float] = GRAVITY_WORLD):
        self.hand = hand
        self.model = pin.Model(hand.model)
        self.data = self.model.createData()
        self.g_world = np.asarray(g_world, dtype=float)

    def torques(self, q: FloatArray, wMb: FloatArray) -> FloatArray:
        """(n_v,) torques [N*m] at joint positions ``q`` (n_q,) with the base at ``wMb``."""
        self.model.gravity.linear = np.asarray(wMb, dtype=float)[:3, :3].T @ self.g_world
        return np.array(pin.computeGeneralizedGravity(self.model, self.data, np.asarray(q)))

    def actuation_torques(self, q: FloatArray, wMb: FloatArray) -> FloatArray:
        """(n_actuation,) what the hand's actuators command to hold its links against gravity
        [N*m], in the coordinates allocators work in: ``C^T g(q)`` for a coupled hand (each
        actuator carries its followers' links too), ``g(q)`` per joint otherwise, zero on joints
        that are not actuated (an assembly's arm, which has its own servo)."""
        g = self.torques(q, wMb)
        hand = self.hand
        if hand.coupled:
            return cast(FloatArray, hand.coupling.T @ g)
        return np.where(hand.actuated_dofs, g, 0.0)
