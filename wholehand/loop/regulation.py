"""The paper's force regulation as a stage: contacts on every link -> QP -> joint torques.

Each cycle, in two halves as the paper's hardware loop runs them (Sec. V-D):

1. estimate the contacts at the object pose and the joint configuration it was measured at,
   ``q(stamp_object)`` (``estimate_at="object_stamp"``, the paper's) or at the current q
   (``estimate_at="current"``, for comparison);
2. carry the contacts with their links to the current q (a no-op when both stamps agree), take
   the point Jacobians there and allocate the forces; ``tau = J_act^T f`` (per actuator,
   ``C^T J_act^T f``, for a hand with coupled joints: :mod:`wholehand.models.coupling`), plus
   the links' gravity torques when ``gravity_compensation`` is on.

With exact, current observations both halves run at one configuration and nothing is moved.

A pose that puts the object out of the hand's reach is a tracker's glitch, not an empty grasp:
status ``tracking_lost``, the last torque held, then ramped to zero (:mod:`wholehand.loop.
tracking`).
"""

from __future__ import annotations

import time
from typing import Literal

import numpy as np
import numpy.typing as npt

from wholehand.allocation.base import Allocator
from wholehand.backends.command import Command
from wholehand.contacts.base import ContactEstimator
from wholehand.contacts.normals import unit_normals
from wholehand.errors import ConfigError
from wholehand.loop.stage import CycleContext, Stage, StageOutput
from wholehand.loop.tracking import TRACKING_LOST, ReachBound, ramp_scale
from wholehand.models.gravity import GravityCompensation
from wholehand.models.hand import HandModel
from wholehand.models.objects import ObjectModel

FloatArray = npt.NDArray[np.float64]

UNIT_TOL = 1e-3
"""Largest deviation of a contact normal's squared length from 1 that counts as a unit vector."""

BAD_CONTACTS = "bad_contacts"
"""Status of a cycle whose estimated contacts all had degenerate normals: no torque (the loop
keeps the last feasible one), since "no contact" would release the grasp on an estimator fault."""

EstimateAt = Literal["object_stamp", "current"]
ESTIMATE_AT: tuple[EstimateAt, ...] = ("object_stamp", "current")
AllocateEvery = Literal["cycle", "pose"]
ALLOCATE_EVERY: tuple[AllocateEvery, ...] = ("cycle", "pose")

POSE_HELD = "pose_held"
"""Status of a cycle that allocates nothing because no new pose arrived
(``allocate_every="pose"``): the loop keeps the torque of the last pose."""


class ForceRegulation(Stage):
    """Estimate contacts on every link, allocate forces, command joint torques.

    Args:
        hand: the hand model.
        obj: the object model (its centre of mass is the reference point of the grasp matrix).
        estimator: a contact-estimator plug-in instance.
        allocator: an allocator plug-in instance.
        estimate_at: ``"object_stamp"``: contacts at q(stamp_object) (paper); ``"current"``: at
            the current q.
        name: the stage's name.
        weight: the object's known weight, world axes [N] (e.g. ``m * (0, 0, -9.81)``): the
            allocator balances it with the contact forces (``G f + w = 0``, a force at the
            centre of mass). None: the paper's quasi-static balance of no external wrench.
        allocate_every: ``"cycle"``: allocate every control cycle at the current q, the
            contacts of the newest pose carried with their links; ``"pose"``: allocate once per
            new object pose and hold that torque until the next (the paper's hardware loop).
        gravity_compensation: the hand's actuators also hold their own links against gravity:
            ``tau = g(q) + J^T f`` with ``g`` from Pinocchio at the current q and base pose
            (:class:`~wholehand.models.gravity.GravityCompensation`), and the allocator keeps
            the sum within the torque limits (it needs ``supports_tau_bias``). False: the
            paper's ``tau = J^T f`` (its studies run without gravity).

    Status: the allocation's (``ok``, ``empty``, ``infeasible``, ``hold``, ...). When the
    allocation gives no torque the stage gives no command and the loop keeps the last feasible
    one.

    A contact whose normal is not a unit vector (an SDF gradient that vanishes inside a thin
    object, NaN) never reaches the allocator: it is dropped and counted in
    :attr:`degenerate_normals`, so it cannot count toward the minimum squeeze; when every
    contact of a cycle is such, the cycle gives no torque (status :data:`BAD_CONTACTS`).
    """

    def __init__(
        self,
        hand: HandModel,
        obj: ObjectModel,
        estimator: ContactEstimator,
        allocator: Allocator,
        estimate_at: EstimateAt = "object_stamp",
        name: str = "regulate",
        weight: npt.ArrayLike | None = None,
        allocate_every: AllocateEvery = "cycle",
        gravity_compensation: bool = False,
    ) -> None:
        if weight is not None and not allocator.supports_external_wrench:
            raise ConfigError(
                f"ForceRegulation: allocator {type(allocator).__name__} cannot balance the "
                "object's weight (supports_external_wrench is False); use the qp allocator or "
                "leave compensation off"
            )
        if gravity_compensation and not allocator.supports_tau_bias:
            raise ConfigError(
                f"ForceRegulation: allocator {type(allocator).__name__} cannot keep the links' "
                "gravity torques within the limits (supports_tau_bias is False); use the qp "
                "allocator or leave gravity_compensation off"
            )
        if estimate_at not in ESTIMATE_AT:
            raise ConfigError(
                f"ForceRegulation: estimate_at={estimate_at!r} is unknown; use one of "
                f"{list(ESTIMATE_AT)}"
            )
        if allocate_every not in ALLOCATE_EVERY:
            raise ConfigError(
                f"ForceRegulation: allocate_every={allocate_every!r} is unknown; use one of "
                f"{list(ALLOCATE_EVERY)}"
            )
        self.allocate_every = allocate_every
        self._allocated_stamp = np.nan
        self.hand, self.obj = hand, obj
        self.estimator, self.allocator = estimator, allocator
        self.estimate_at = estimate_at
        self.name = name
        self._com_h = np.r_[np.asarray(obj.com, dtype=float), 1.0]
        self._extra: dict[str, FloatArray] = {}
        if weight is not None:
            force = np.asarray(weight, dtype=float).reshape(-1)
            if force.shape != (3,) or not np.isfinite(force).all():
                raise ConfigError(
                    f"ForceRegulation: weight must be 3 finite numbers [N], got {weight!r}"
                )
            self._extra["external_wrench"] = np.r_[force, 0.0, 0.0, 0.0]
        self.gravity = GravityCompensation(hand) if gravity_compensation else None
        """The links' gravity torques, when compensated."""
        self.degenerate_normals = 0
        """Contacts dropped because their normal was not a unit vector."""
        self.reach = ReachBound(hand, obj)
        """Which poses the hand can be touching (:mod:`wholehand.loop.tracking`)."""
        self.lost_since: float | None = None
        """Time tracking was lost [s] (None: it is not)."""
        self._last: Command | None = None

    def preload(self, context: CycleContext) -> None:
        """Load the estimator's kernels and the normals' compiled check."""
        unit_normals(np.zeros((0, 3)), UNIT_TOL)
        # A wrapper that does not subclass ContactEstimator may have no preload.
        preload = getattr(self.estimator, "preload", None)
        if preload is not None and context.obs.wMo is not None:
            preload(context.kinematics, context.obs.wMo)

    def start(self, context: CycleContext) -> None:
        """Let the allocator prepare (baselines allocate once here)."""
        self.allocator.start(context)
        self.lost_since, self._last = None, None

    def tracking_lost(self, context: CycleContext) -> float | None:
        """How long [s] the pose has put the object out of the hand's reach (None: it does not
        now)."""
        assert context.obs.wMo is not None
        if not self.reach.out_of_reach(context.kinematics, context.obs.wMo):
            self.lost_since = None
            return None
        if self.lost_since is None:
            self.lost_since = context.t
        return context.t - self.lost_since

    def _hold_then_ramp(self, held: float) -> StageOutput:
        """Tracking lost for ``held`` [s]: the last torque kept, then ramped to zero."""
        scale = ramp_scale(held)
        if self._last is None or scale == 1.0:
            return StageOutput(None, TRACKING_LOST)
        last = self._last
        return StageOutput(Command(last.tau * scale, last.targets, last.base), TRACKING_LOST)

    def step(self, context: CycleContext) -> StageOutput:
        started = time.perf_counter()
        obs = context.obs
        wMo = obs.wMo
        assert wMo is not None  # the loop runs no stage without a pose
        held = self.tracking_lost(context)
        if held is not None:
            return self._hold_then_ramp(held)
        if self.allocate_every == "pose":
            if obs.stamp_object == self._allocated_stamp:
                return StageOutput(None, POSE_HELD)
            self._allocated_stamp = obs.stamp_object
        now = context.kinematics
        then = context.kinematics_object if self.estimate_at == "object_stamp" else now
        contacts = self.estimator.estimate(then, wMo, stamp=obs.stamp_object)
        unit, every = unit_normals(contacts.n_world, UNIT_TOL)  # False for NaN
        if not every:
            self.degenerate_normals += int((~unit).sum())
            if not unit.any():
                return StageOutput(None, BAD_CONTACTS, contacts.select(unit))
            contacts = contacts.select(unit)
        if then is not now:
            contacts = contacts.in_joint_frames(then).moved_to(now)
        estimated = time.perf_counter()
        J = now.actuation_jacobians(self.hand.link_joint[contacts.link], contacts.p_world)
        p_com = (wMo @ self._com_h)[:3]
        extra = self._extra
        bias = None
        if self.gravity is not None:
            bias = self.gravity.actuation_torques(obs.q, obs.wMb)
            extra = {**extra, "tau_bias": bias}
        allocation = self.allocator.allocate(contacts, J, p_com, now, **extra)
        tau = allocation.tau
        if tau is not None and bias is not None:
            tau = tau + bias
        command = None if tau is None else Command.torques(self.hand.joint_torques(tau))
        if command is not None:
            self._last = command
        return StageOutput(
            command, allocation.status.value, contacts, allocation, estimated - started
        )
