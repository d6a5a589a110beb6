"""The perturbation protocol of the paper's simulation studies (Fig. 2), and its driver.

Phases: settle; load test (a force of 0.1 m g for 1 s along +x, -x, +y, -y, +z, -z in turn); a
spring-damper wrench pulls the object toward its initial pose rotated by theta about a random
axis; the load test again. The paper gives no spring constants: ours are named below.

:class:`ProtocolDriver` plays the protocol as a loop observer: the phase of each cycle comes from
the backend's clock, and before the backend advances it sets the phase's wrench or spring. It
needs a backend that can push the object (:class:`~wholehand.backends.base.PushesObject`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import cast

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand import defaults
from wholehand.backends.base import PushesObject
from wholehand.errors import ConfigError
from wholehand.loop.control_loop import ControlLoop, Cycle, Observer
from wholehand.models.objects import ObjectModel

FloatArray = npt.NDArray[np.float64]

SETTLE_TIME = 0.5
"""Time the grasp settles under force regulation before any load [s]."""
ROTATION_TIME = 1.5
"""Duration of the rotational pull [s]."""
ROT_STIFFNESS = 0.3
"""Rotational spring of the pull, toward the rotated pose [N*m/rad]: 0.31 N*m at 60 deg,
about the friction torque a 10 N squeeze resists on a 5 cm object."""
ROT_DAMPING_RATIO = 1.0
"""Damping ratio of the rotational pull on the free object (damping 2 * ratio * sqrt(k I))."""
LIN_STIFFNESS = 100.0
"""Translational spring holding the object's centre at its initial place during the pull [N/m]."""
LIN_DAMPING_RATIO = 1.0
"""Damping ratio of the translational spring on the free object."""
SUPPORT_SAG = 1e-3
"""Sag of the object's centre under its weight on the support of a supported settle [m]: the
support's translational stiffness is ``m g / SUPPORT_SAG``."""

DIRECTIONS = {
    "+x": (1.0, 0.0, 0.0),
    "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "-z": (0.0, 0.0, -1.0),
}


@dataclass(frozen=True)
class Phase:
    """One phase of the protocol."""

    name: str
    """e.g. "settle", "load +x", "rotate", "load2 -z"."""
    duration: float
    """[s]"""
    kind: str
    """"settle", "load" or "rotate"."""
    direction: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Unit load direction in the world, for load phases."""


def check_phases_rate(phases: list[Phase], rate: float) -> None:
    """Raise :class:`ConfigError` unless each of ``phases`` with a duration gets a control
    cycle at ``rate`` [Hz] (a phase shorter than half a period would be skipped silently)."""
    for phase in phases:
        if phase.duration > 0.0 and phase.duration * rate < 0.5:
            raise ConfigError(
                f"control rate {rate} Hz gives no cycle in phase {phase.name!r} "
                f"({phase.duration} s); use at least {1.0 / phase.duration:g} Hz"
            )


@dataclass(frozen=True)
class PerturbationProtocol:
    """Phase sequence and the external wrench applied in each phase.

    Args:
        theta_deg: rotation of the pull target [deg]; 0 skips the pull and the second load test.
        seed: seeds the random rotation axis.
    """

    theta_deg: float = 60.0
    seed: int = 0
    settle_time: float = SETTLE_TIME
    load_fraction: float = defaults.LOAD_FRACTION_OF_WEIGHT
    load_duration: float = defaults.LOAD_DURATION
    rotation_time: float = ROTATION_TIME
    rot_stiffness: float = ROT_STIFFNESS
    rot_damping_ratio: float = ROT_DAMPING_RATIO
    lin_stiffness: float = LIN_STIFFNESS
    lin_damping_ratio: float = LIN_DAMPING_RATIO
    supported_settle: bool = False
    """Hold the object at its initial pose with the pull's springs during the settle phase, so
    that the grasp closes before it bears anything (with gravity on: the object's weight from
    the end of the settle, as when a support is taken away)."""
    axis: FloatArray = field(init=False)

    def __post_init__(self) -> None:
        if not (isinstance(self.seed, int | np.integer) and self.seed >= 0):
            raise ConfigError(
                f"PerturbationProtocol: seed must be an integer >= 0, got {self.seed!r}"
            )
        if not (np.isfinite(self.theta_deg) and self.theta_deg >= 0.0):
            raise ConfigError(
                f"PerturbationProtocol: theta_deg must be a finite angle >= 0 [deg], got "
                f"{self.theta_deg!r}"
            )
        axis = np.random.default_rng(self.seed).standard_normal(3)
        object.__setattr__(self, "axis", axis / np.linalg.norm(axis))

    def check_rate(self, rate: float) -> None:
        """Raise :class:`ConfigError` unless every phase with a duration gets a control cycle at
        ``rate`` [Hz] (a phase shorter than half a period would be skipped silently)."""
        check_phases_rate(self.phases(), rate)

    def phases(self) -> list[Phase]:
        """The phases in order."""
        out = [Phase("settle", self.settle_time, "settle")]
        loads = [Phase(f"load {n}", self.load_duration, "load", d) for n, d in DIRECTIONS.items()]
        out += loads
        if self.theta_deg > 0.0:
            out.append(Phase("rotate", self.rotation_time, "rotate"))
            out += [Phase(f"load2 {s.name[5:]}", s.duration, "load", s.direction) for s in loads]
        return out

    @property
    def duration(self) -> float:
        """Total duration [s]."""
        return float(sum(s.duration for s in self.phases()))

    def target_rotation(self, wRo_initial: FloatArray) -> FloatArray:
        """(3, 3) world orientation the pull drives the object toward."""
        return cast(FloatArray, pin.exp3(np.deg2rad(self.theta_deg) * self.axis) @ wRo_initial)

    def spring(
        self,
        mass: float,
        inertia: FloatArray,
        com: FloatArray,
        wMo_initial: FloatArray,
        rotate: bool = True,
    ) -> tuple[FloatArray, tuple[float, float], tuple[float, float]]:
        """Target pose (4, 4), stiffness and damping of the rotational pull (see
        :meth:`~wholehand.backends.base.PushesObject.set_object_spring`).

        Args:
            mass: object mass [kg]; inertia: (3, 3) about its centre of mass [kg*m^2].
            com: (3,) centre of mass in the object frame [m].
            wMo_initial: (4, 4) the object pose at the start of the protocol.
            rotate: False: springs holding the initial pose (a supported settle), the
                translational one stiff enough that the weight sags it by ``SUPPORT_SAG``.
        """
        # Rotate about the centre of mass, which the translational spring holds in place.
        target = np.eye(4)
        R0 = wMo_initial[:3, :3]
        target[:3, :3] = self.target_rotation(R0) if rotate else R0
        p_com = wMo_initial[:3, :3] @ com + wMo_initial[:3, 3]
        target[:3, 3] = p_com - target[:3, :3] @ com
        i_min = float(np.linalg.eigvalsh(inertia).min())
        k_lin = self.lin_stiffness if rotate else mass * defaults.GRAVITY / SUPPORT_SAG
        damping = (
            2.0 * self.lin_damping_ratio * np.sqrt(k_lin * mass),
            2.0 * self.rot_damping_ratio * np.sqrt(self.rot_stiffness * i_min),
        )
        return target, (k_lin, self.rot_stiffness), damping

    def load_force(self, phase: Phase, mass: float) -> FloatArray:
        """(3,) external force on the centre of mass in a load phase, else zero [N], world axes."""
        if phase.kind != "load":
            return np.zeros(3)
        return self.load_fraction * mass * defaults.GRAVITY * np.asarray(phase.direction)


def object_pusher(loop: ControlLoop, protocol: str) -> PushesObject:
    """The loop's backend, which a protocol needs to push the object; else a ConfigError."""
    backend = loop.backend
    if not isinstance(backend, PushesObject):
        raise ConfigError(
            f"the {protocol} protocol needs a backend that can push the object "
            f"(PushesObject); {type(backend).__name__} cannot"
        )
    return backend


class PhasedDriver(Observer):
    """An observer that plays phases on the backend's clock from the start of the run.

    The phase of a cycle at backend time ``t`` (from the start of the run) is the one whose
    interval holds ``t + dt / 2``, so float rounding of the clock never shifts a boundary.
    Subclasses call :meth:`start_clock` in ``on_start``.
    """

    def __init__(self, phases: list[Phase]) -> None:
        self.phases = phases
        self._ends = np.cumsum([p.duration for p in phases])
        self.phase_index = 0
        """Phase of the latest cycle."""
        self._t0 = 0.0
        self._half_dt = 0.0

    @property
    def phase_names(self) -> list[str]:
        return [p.name for p in self.phases]

    def start_clock(self, loop: ControlLoop) -> None:
        """Phase 0 starts now, at the backend's current time."""
        self._t0 = loop.backend.time
        self._half_dt = 0.5 * loop.dt

    def phase_at(self, t: float) -> int:
        """Index of the phase at backend time ``t`` (the last one past the end)."""
        i = int(np.searchsorted(self._ends, t - self._t0 + self._half_dt, side="right"))
        return min(i, len(self.phases) - 1)


class ProtocolDriver(PhasedDriver):
    """Plays a :class:`PerturbationProtocol` over the loop's backend.

    After each cycle's command the driver sets that phase's load force, or the rotational
    spring during the pull; both are removed when the run ends. Run the loop for
    :attr:`PerturbationProtocol.duration`.

    Args:
        protocol: the protocol.
        obj: the object model (mass, inertia and centre of mass size the load and the spring).
    """

    def __init__(self, protocol: PerturbationProtocol, obj: ObjectModel) -> None:
        super().__init__(protocol.phases())
        self.protocol, self.obj = protocol, obj
        self._backend: PushesObject | None = None
        self._spring: str | None = None
        """The spring set on the object: ``"rotate"`` (the pull), ``"hold"`` or None."""
        self._wMo0 = np.eye(4)

    def on_start(self, loop: ControlLoop) -> None:
        self._backend = object_pusher(loop, "perturbation")
        self.start_clock(loop)
        wMo = loop.backend.observe().wMo
        assert wMo is not None
        self._wMo0 = wMo.copy()

    def on_cycle(self, cycle: Cycle) -> str | None:
        backend = self._backend
        assert backend is not None
        self.phase_index = self.phase_at(cycle.t)
        phase = self.phases[self.phase_index]
        rotating = phase.kind == "rotate"
        holding = phase.kind == "settle" and self.protocol.supported_settle
        spring = "rotate" if rotating else "hold" if holding else None
        if spring != self._spring:
            if spring is None:
                backend.set_object_spring(None)
            else:
                obj = self.obj
                backend.set_object_spring(
                    *self.protocol.spring(obj.mass, obj.inertia, obj.com, self._wMo0, rotating)
                )
        self._spring = spring
        backend.apply_object_wrench(self.protocol.load_force(phase, self.obj.mass), _NO_TORQUE)
        return None

    def on_end(self, loop: ControlLoop) -> None:
        if self._backend is not None:
            self._backend.set_object_spring(None)
            self._backend.apply_object_wrench(np.zeros(3), np.zeros(3))
        self._spring = None


_NO_TORQUE = np.zeros(3)
