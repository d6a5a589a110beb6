"""The backend interface: where commands go and observations come from (simulation or hardware).

Every backend can be read (:meth:`Backend.observe`), commanded (:meth:`Backend.apply`) and
advanced in time (:meth:`Backend.step`) on its own clock. Anything more is an optional
capability, declared by deriving from one of the classes below, and checked with
``isinstance`` where a caller needs it:

- :class:`PushesObject`: external wrench and a spring-damper on the object (the perturbation
  protocol needs it; a real robot cannot).
- :class:`PushesBodies`: a force on the object or on one hand link over a window of simulated
  time, evaluated at every simulation step (the fast-disturbance protocol).
- :class:`HasGroundTruth`: the simulator's own contacts and forces (baselines that allocate once
  from ground truth, studies, tests). The controller never sees them.
- :class:`Resettable`: restart at a given joint configuration and object pose.
- :class:`ReportsWarnings`: counts of the simulator's warnings (divergence).
"""

from __future__ import annotations

import abc
from typing import TYPE_CHECKING, Literal

import numpy as np
import numpy.typing as npt

from wholehand.backends.command import Command
from wholehand.backends.observation import Observation

if TYPE_CHECKING:
    from wholehand.backends.ground_truth import SimContacts

FloatArray = npt.NDArray[np.float64]

Clock = Literal["sim", "wall"]


class Backend(abc.ABC):
    """A hand-object system that can be read, commanded and advanced in time.

    Registered in the ``wholehand.backends`` entry-point group. Constructed with the keywords
    ``hand``, ``obj``, ``q_init`` ((n_q,) joint positions), ``wMo_init`` ((4, 4) object pose),
    ``gravity`` (bool) and the backend's own options.
    """

    clock: Clock = "sim"
    """``"sim"``: :meth:`step` advances simulated time at once; ``"wall"``: time passes on its own
    and :meth:`step` waits, so a cycle that computes too long overruns (the loop records it)."""

    @abc.abstractmethod
    def observe(self) -> Observation:
        """The latest sample of every stream, with the joint history."""

    @abc.abstractmethod
    def apply(self, command: Command) -> None:
        """Send a command (torques and/or joint targets), held until the next one; torques are
        clamped to the joints' limits."""

    @abc.abstractmethod
    def step(self, duration: float) -> None:
        """Advance time by ``duration`` [s] (simulation) or wait that long (hardware)."""

    @property
    @abc.abstractmethod
    def time(self) -> float:
        """Current time of the backend's clock [s]."""


class PushesObject(abc.ABC):
    """Capability: push the object with an external wrench or a spring-damper (simulation)."""

    @abc.abstractmethod
    def apply_object_wrench(self, force_world: FloatArray, torque_world: FloatArray) -> None:
        """Apply an external force [N] and torque [N*m] at the object's centre of mass, world
        axes, held until changed."""

    @abc.abstractmethod
    def set_object_spring(
        self,
        wMo_target: FloatArray | None,
        stiffness: tuple[float, float] = (0.0, 0.0),
        damping: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        """Pull the object toward a target pose with a spring-damper evaluated at every
        simulation step (stable where a wrench held over a control period would not be).

        Args:
            wMo_target: (4, 4) target object pose; None removes the spring.
            stiffness: translational [N/m] (on the centre of mass) and rotational [N*m/rad].
            damping: translational [N*s/m] and rotational [N*m*s/rad].
        """


class PushesBodies(abc.ABC):
    """Capability: push the object or a hand link with a force over a window of simulated time,
    evaluated at every simulation step, so that a push shorter than a control period lands
    whole and at its own time (simulation)."""

    @abc.abstractmethod
    def schedule_push(
        self, force_world: FloatArray, start: float, duration: float, link: str | None = None
    ) -> None:
        """Push with ``force_world`` (3,) [N], world axes, at the centre of mass of the object
        (``link`` None) or of the hand link named ``link``, during the simulation steps that
        start in ``[start, start + duration)`` of the backend's clock [s]. Pushes add up to
        any other external wrench; :meth:`clear_pushes` or a reset removes them."""

    @abc.abstractmethod
    def clear_pushes(self) -> None:
        """Remove every scheduled push."""


class HasGroundTruth(abc.ABC):
    """Capability: the simulator's hand-object contacts."""

    @abc.abstractmethod
    def ground_truth_contacts(self) -> SimContacts:
        """Contacts and forces at the current state, world frame (see
        :class:`~wholehand.backends.ground_truth.SimContacts`)."""


class Resettable(abc.ABC):
    """Capability: restart at a joint configuration and an object pose."""

    @abc.abstractmethod
    def reset(self, q: FloatArray, wMo: FloatArray) -> None:
        """Restart at time 0 with joint positions ``q`` (n_q,), object pose ``wMo`` (4, 4), zero
        velocities and no command."""


class ReportsWarnings(abc.ABC):
    """Capability: counts of the simulator's run-time warnings."""

    @abc.abstractmethod
    def warnings(self) -> dict[str, int]:
        """Warning name -> count since the last reset (all zero in a healthy simulation)."""
