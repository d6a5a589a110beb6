"""The grasp generator's closing phase (:mod:`wholehand.grasps.generate`): the fingers close
with constant torques while the other joints hold the pre-shape."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from wholehand.backends.command import Command
from wholehand.loop.stage import END, CycleContext, Stage, StageOutput

FloatArray = npt.NDArray[np.float64]

PD_GAINS = (2.0, 0.05)
"""PD gains holding the non-closing joints at the pre-shape: [N*m/rad], [N*m*s/rad]."""

Closing = tuple[FloatArray, FloatArray, npt.NDArray[np.bool_]]
"""How a hand closes (:class:`ClosingStage`): the pose the other joints hold (n_q,) [rad], the
closing torques (n_v,) [N*m] and which joints close (n_v,) bool."""


class ClosingStage(Stage):
    """The generator's closing phase: constant torques on the closing joints, a PD law holding
    the other joints at the pre-shape; the PD law runs at the control rate (it is part of the
    stage, not the backend's servo).

    Exit: when ``until`` (if given) holds, checked every ``check_every`` cycles (from the
    ``check_every``-th) on the state the cycle observes; :attr:`closed` then says so.

    Args:
        q_pre: (n_q,) pre-shape [rad]; tau_close: (n_v,) closing torques [N*m]; closing: (n_v,)
            bool, the closing joints; gains: PD gains [N*m/rad], [N*m*s/rad].
    """

    name = "close"
    needs_object_pose = False

    def __init__(
        self,
        q_pre: FloatArray,
        tau_close: FloatArray,
        closing: npt.NDArray[np.bool_],
        gains: tuple[float, float] = PD_GAINS,
        until: Callable[[], bool] | None = None,
        check_every: int = 5,
    ) -> None:
        self.q_pre, self.tau_close, self.closing = q_pre, tau_close, closing
        self.gains, self.until, self.check_every = gains, until, check_every
        self.cycles = 0
        self.closed = False

    def step(self, context: CycleContext) -> StageOutput:
        if (
            self.until is not None
            and self.cycles
            and self.cycles % self.check_every == 0
            and self.until()
        ):
            self.closed = True
            return StageOutput(None, "closed", next=END)
        self.cycles += 1
        obs = context.obs
        tau = self.gains[0] * (self.q_pre - obs.q) - self.gains[1] * obs.dq
        tau[self.closing] = self.tau_close[self.closing]
        return StageOutput(Command.torques(tau), "closing")
