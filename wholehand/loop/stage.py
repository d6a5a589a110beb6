"""Stages of the control loop: what runs each cycle, its per-cycle context and its output.

A stage (force regulation, the grasp generator's closing phase, reaching) turns one
:class:`CycleContext` into a :class:`StageOutput`: a command, or None to keep the last feasible
command, a status, and, when it is done, the name of the stage that follows.
"""

from __future__ import annotations

import abc
import enum
import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, ClassVar

from wholehand.backends.command import Command
from wholehand.backends.observation import Observation

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from wholehand.allocation.base import Allocation
    from wholehand.contacts.base import ContactSet
    from wholehand.models.hand import HandModel
    from wholehand.models.kinematics import HandKinematics
    from wholehand.models.objects import ObjectModel

END = "end"
"""``StageOutput.next`` value that ends the run."""


class LoopStatus(str, enum.Enum):
    """Statuses the loop itself gives a cycle (a stage's own statuses are its business)."""

    BAD_STATE = "bad_state"
    """The observation was unusable (:class:`~wholehand.errors.ObservationError`); the last
    feasible command is kept."""
    STAGE_ERROR = "stage_error"
    """The stage raised an unexpected exception; the last feasible command is kept and the
    traceback is reported at the end of the run."""
    NO_POSE = "no_pose"
    """No object pose has arrived yet; the last feasible command (initially zero) is kept."""


class CycleContext:
    """What a stage sees in one cycle: the (filtered) observation and the hand's kinematics.

    ``kinematics`` is the hand at the current joint reading ``q(stamp_q)``; ``kinematics_object``
    the hand at ``q(stamp_object)``, the configuration the object pose was measured at (the same
    object when the two stamps agree). Both are computed on first use, so a stage that needs no
    kinematics pays nothing. They belong to the loop and are updated in place every cycle: read
    them during the cycle, never keep a reference.

    Attributes:
        t: backend time at the start of the cycle [s].
        dt: control period [s].
        obs: the observation the controller sees (after the observation filters).
        hand, obj: the hand and object models.
        ground_truth: the simulator's contacts mapped into the object pose the controller sees
            (None when the backend has no ground truth); for baselines and studies.
    """

    def __init__(
        self,
        t: float,
        dt: float,
        obs: Observation,
        hand: HandModel,
        obj: ObjectModel,
        kinematics_now: HandKinematics,
        kinematics_then: HandKinematics,
        ground_truth: Callable[[], ContactSet] | None = None,
    ) -> None:
        self.t, self.dt, self.obs, self.hand, self.obj = t, dt, obs, hand, obj
        self._now, self._then = kinematics_now, kinematics_then
        self.ground_truth = ground_truth

    @cached_property
    def kinematics(self) -> HandKinematics:
        """The hand at the current joint reading (q, wMb at ``stamp_q``)."""
        self._now.update(self.obs.q, self.obs.wMb)
        return self._now

    @cached_property
    def kinematics_object(self) -> HandKinematics:
        """The hand at ``q(stamp_object)``: the configuration the object pose belongs to."""
        obs = self.obs
        if obs.stamp_object == obs.stamp_q:
            return self.kinematics
        q, wMb = obs.q_at(obs.stamp_object)
        self._then.update(q, wMb)
        return self._then


@dataclass(frozen=True)
class StageOutput:
    """What a stage produced in one cycle."""

    command: Command | None
    """The command to apply; None keeps the last feasible command (``status`` says why)."""
    status: str
    """Why the command is what it is (e.g. an :class:`~wholehand.allocation.base.
    AllocationStatus` value), stored by name in records."""
    contacts: ContactSet | None = None
    """The contacts the stage used, world frame at the current q (None: none estimated)."""
    allocation: Allocation | None = None
    """The force allocation of the cycle (force regulation only)."""
    estimate_time: float = 0.0
    """Kinematics plus contact estimation [s]."""
    next: str | None = None
    """None: stay; a stage name: switch to it next cycle; :data:`END`: end the run now."""
    reason: str = ""
    """Why the stage switches (with ``next``), kept in the loop's transitions."""


class Stage(abc.ABC):
    """One mode of the controller, run by :class:`~wholehand.loop.control_loop.ControlLoop`."""

    name: str = "stage"
    """Name of the stage in records and transitions."""
    needs_object_pose: ClassVar[bool] = True
    """Until a first object pose arrives, the loop runs no stage that needs one (status
    ``no_pose``, last feasible command kept)."""

    def preload(self, context: CycleContext) -> None:  # noqa: B027 - optional hook
        """Called once by the loop before its first cycle, with its first joint reading and the
        object at the world origin: load now what a first :meth:`step` would load in a cycle
        (a plug-in's compiled kernels, :meth:`ContactEstimator.preload
        <wholehand.contacts.base.ContactEstimator.preload>`), leaving no state behind."""

    def start(self, context: CycleContext) -> None:  # noqa: B027 - optional hook
        """Called on the first cycle the stage is active, before :meth:`step`."""

    @abc.abstractmethod
    def step(self, context: CycleContext) -> StageOutput:
        """One cycle: the command and status; ``next`` set when the exit condition holds."""


def preload_all(stages: Iterable[Stage], context: CycleContext) -> None:
    """Each distinct stage's :meth:`Stage.preload` with ``context``. A preload that raises is
    logged; the stage's cycles then meet the fault and report it."""
    for stage in {id(s): s for s in stages}.values():
        try:
            stage.preload(context)
        except Exception as err:  # noqa: BLE001 - not in a cycle; the cycles report it
            log.warning("stage %r: preload raised %s: %s", stage.name, type(err).__name__, err)
