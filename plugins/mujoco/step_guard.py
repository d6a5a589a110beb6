"""A MuJoCo step that takes a failed contact solve again instead of diverging.

MuJoCo's Newton solver with elliptic friction cones can fail on a frictional contact between a
hand's own collision shapes (the Allegro's finger boxes overlap where the fingers splay): the
solve ends at its iteration cap, or converges to forces of 1e5-1e10 N, and the step leaves joint
speeds of 1e3-1e7 rad/s (docs/results.md, "Why MuJoCo diverged"). A few steps later MuJoCo
reports ``bad_qacc`` and resets the simulation to its initial state, which ends the trial as
"diverged".

:class:`StepGuard` keeps the state before every step. A step that ends faster than
:data:`MAX_SPEED` (a free body turning faster than :data:`MAX_SPIN`), or raises ``bad_qacc``, is
taken again from that state with frictionless hand-hand contacts (``condim`` 1 on the hand's
geoms, for that one step). Hand-object and hand-table contacts keep their friction: the
object's geoms have the higher ``priority``, so their contact model wins, and the table's
``condim`` is the larger one. A step that passes the check is never changed, so a simulation
without failed solves is bit-identical with or without the guard.
"""

from __future__ import annotations

import mujoco
import numba
import numpy as np
import numpy.typing as npt

from wholehand.jit import CACHE

MAX_SPEED = 100.0
"""Fastest joint or object speed [rad/s or m/s] a step may end with. The Allegro's joints move
at most a few rad/s and an object shaken loose at a few m/s; a failed solve leaves 1e3-1e7."""
MAX_SPIN = 1000.0
"""Fastest turn of a free body [rad/s] (an object, a floating wrist) a step may end with. An
object torn out of the hand by the reach episode's snatch spins at up to about 110 rad/s
(a small cube, legitimately); a failed solve leaves thousands."""

_STATE = mujoco.mjtState.mjSTATE_INTEGRATION
_BAD_QACC = int(mujoco.mjtWarning.mjWARN_BADQACC)


class StepGuard:
    """Steps one ``MjData`` of ``model``; a step whose contact solve failed is taken again with
    frictionless contacts between the geoms of ``hand_geoms``.

    Args:
        model: the compiled scene.
        hand_geoms: (ngeom,) bool mask of the hand's (and arm's) collision geoms.

    Attributes:
        retries: steps taken again since the last :meth:`clear`.
        failed_retries: retried steps that failed too (too fast, or MuJoCo's ``bad_qacc``: it
            then resets the simulation, as without the guard).
    """

    def __init__(self, model: mujoco.MjModel, hand_geoms: npt.NDArray[np.bool_]) -> None:
        self.model = model
        self._geoms = np.flatnonzero(hand_geoms)
        self._condim = model.geom_condim[self._geoms].copy()
        self._saved = np.empty(mujoco.mj_stateSize(model, _STATE))
        self._limits = speed_limits(model)
        self.retries = 0
        self.failed_retries = 0
        _within(np.zeros(model.nv), self._limits)  # load the compiled check now

    def clear(self) -> None:
        """Zero the counts (at a simulation reset)."""
        self.retries = 0
        self.failed_retries = 0

    def step(self, data: mujoco.MjData) -> None:
        """One ``mj_step``, retried once as described in the module docstring."""
        m = self.model
        mujoco.mj_getState(m, data, self._saved, _STATE)
        bad_before = data.warning[_BAD_QACC].number
        mujoco.mj_step(m, data)
        if data.warning[_BAD_QACC].number == bad_before and self._calm(data):
            return
        mujoco.mj_setState(m, data, self._saved, _STATE)
        data.warning[_BAD_QACC].number = bad_before
        m.geom_condim[self._geoms] = 1
        try:
            mujoco.mj_step(m, data)
        finally:
            m.geom_condim[self._geoms] = self._condim
        self.retries += 1
        if data.warning[_BAD_QACC].number != bad_before or not self._calm(data):
            self.failed_retries += 1

    def _calm(self, data: mujoco.MjData) -> bool:
        """Every speed within its limit (False for NaN)."""
        return bool(_within(data.qvel, self._limits))


@numba.njit(cache=CACHE, nogil=True)
def _within(v: npt.NDArray[np.float64], limits: npt.NDArray[np.float64]) -> bool:
    """``|v| <= limits`` everywhere (False for NaN); compiled, since it runs after every step."""
    for i in range(v.size):
        if not abs(v[i]) <= limits[i]:
            return False
    return True


def speed_limits(model: mujoco.MjModel) -> npt.NDArray[np.float64]:
    """(nv,) fastest speed of each degree of freedom a step may end with: :data:`MAX_SPIN` for
    the turning ones of free joints, :data:`MAX_SPEED` for the rest."""
    limits = np.full(model.nv, MAX_SPEED)
    for j in np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_FREE):
        start = int(model.jnt_dofadr[j]) + 3  # a free joint's dofs: 3 linear, then 3 angular
        limits[start : start + 3] = MAX_SPIN
    return limits
