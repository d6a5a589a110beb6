"""Fast disturbances: a short push on the object, a sudden pull, a knock on one finger.

The perturbation protocol's loads and pull build up over hundreds of milliseconds, slower than
any control rate the rate study tried. These act within one simulation step and last 10-300
ms, shorter than a period at 30 Hz, so that how fast the controller answers (its rate, and how
long a cycle computes) can decide whether the grasp holds.

Phases: ``settle`` (the grasp closes under force regulation), then one phase named by the
disturbance: the push and the recovery after it. The push is scheduled on the backend's clock
(:class:`~wholehand.backends.base.PushesBodies`), evaluated at every simulation step, so it lands
at the same time and with the same impulse whatever the control rate.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from wholehand import defaults
from wholehand.backends.base import HasGroundTruth, PushesBodies
from wholehand.errors import ConfigError
from wholehand.loop.control_loop import ControlLoop, Cycle
from wholehand.models.hand import HandModel
from wholehand.models.objects import ObjectModel
from wholehand.trials.protocol import SETTLE_TIME, Phase, PhasedDriver, check_phases_rate

FloatArray = npt.NDArray[np.float64]

IMPULSE_G = 3.0
"""Force of an impulse on the object, in multiples of its weight ``m g``: over 10, 20 and 50 ms
it would change a free object's velocity by 0.29, 0.59 and 1.5 m/s."""
PULL_G = 1.0
"""Force of the sudden pull on the object, in multiples of its weight: ten times the paper's
load test, applied within one simulation step instead of held for a second."""
PULL_TIME = 0.3
"""How long the sudden pull lasts [s]."""
KNOCK_FORCE = 5.0
"""Force of the knock on one finger's link, away from the object [N]: more than twice what a
fingertip of the shipped hands presses with at its motors' 0.2 N*m on about 0.1 m (2 N)."""
KNOCK_TIME = 0.03
"""How long the knock lasts [s]."""
RECOVERY_TIME = 0.5
"""Time after the push until the trial ends [s]: a grasp must hold through it."""


@dataclass(frozen=True)
class Disturbance:
    """One kind of fast disturbance."""

    target: Literal["object", "finger"]
    """``"object"``: a force on the object's centre of mass along a seeded random direction;
    ``"finger"``: a force on one seeded finger link touching the object, away from it."""
    duration: float
    """How long the force acts [s]."""
    magnitude: float
    """Object: the force in multiples of the object's weight ``m g``; finger: the force [N]."""

    def force(self, mass: float) -> float:
        """The force's magnitude [N] on an object of ``mass`` [kg]."""
        if self.target == "finger":
            return self.magnitude
        return self.magnitude * mass * defaults.GRAVITY


DISTURBANCES = {
    "impulse_10ms": Disturbance("object", 0.010, IMPULSE_G),
    "impulse_20ms": Disturbance("object", 0.020, IMPULSE_G),
    "impulse_50ms": Disturbance("object", 0.050, IMPULSE_G),
    "pull": Disturbance("object", PULL_TIME, PULL_G),
    "knock": Disturbance("finger", KNOCK_TIME, KNOCK_FORCE),
}
"""The fast disturbances by name."""


@dataclass(frozen=True)
class DisturbanceProtocol:
    """Settle, then one fast disturbance and the recovery after it.

    Args:
        kind: a name of :data:`DISTURBANCES`.
        seed: seeds the push's direction (object) or the finger it knocks.
        settle_time: [s] before the push; recovery_time: [s] after it.
    """

    kind: str
    seed: int = 0
    settle_time: float = SETTLE_TIME
    recovery_time: float = RECOVERY_TIME
    direction: FloatArray = field(init=False)
    """(3,) unit direction of a push on the object, world axes."""
    pick: float = field(init=False)
    """In [0, 1): which of the fingers touching the object a knock hits."""

    def __post_init__(self) -> None:
        if self.kind not in DISTURBANCES:
            raise ConfigError(
                f"disturbance {self.kind!r} is unknown; use one of {list(DISTURBANCES)}"
            )
        if not (isinstance(self.seed, int | np.integer) and self.seed >= 0):
            raise ConfigError(
                f"DisturbanceProtocol: seed must be an integer >= 0, got {self.seed!r}"
            )
        for name in ("settle_time", "recovery_time"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0.0):
                raise ConfigError(f"DisturbanceProtocol: {name} must be > 0 [s], got {value!r}")
        rng = np.random.default_rng(self.seed)
        direction = rng.standard_normal(3)
        object.__setattr__(self, "direction", direction / np.linalg.norm(direction))
        object.__setattr__(self, "pick", float(rng.random()))

    @property
    def disturbance(self) -> Disturbance:
        return DISTURBANCES[self.kind]

    def phases(self) -> list[Phase]:
        """``settle``, then the disturbance with its recovery."""
        during = self.disturbance.duration + self.recovery_time
        return [Phase("settle", self.settle_time, "settle"), Phase(self.kind, during, "disturb")]

    @property
    def duration(self) -> float:
        """Total duration [s]."""
        return float(sum(p.duration for p in self.phases()))

    def check_rate(self, rate: float) -> None:
        """Raise :class:`ConfigError` unless every phase gets a control cycle at ``rate`` [Hz]."""
        check_phases_rate(self.phases(), rate)


class DisturbanceDriver(PhasedDriver):
    """Schedules a :class:`DisturbanceProtocol`'s push when the run starts, and tells the
    recorder the phase of each cycle. Run the loop for :attr:`DisturbanceProtocol.duration`.

    A knock hits one of the links touching the object at the start (the simulator's contacts),
    fingertips first; the palm never. Its force points along the mean of that link's contact
    normals, out of the object.

    Attributes:
        event: what was pushed, filled at the start: ``kind``, ``target`` (``"object"`` or the
            link's name), ``force`` (3,) [N] world axes, ``start`` [s from the run's start],
            ``duration`` [s].
    """

    def __init__(self, protocol: DisturbanceProtocol, hand: HandModel, obj: ObjectModel) -> None:
        super().__init__(protocol.phases())
        self.protocol, self.hand, self.obj = protocol, hand, obj
        self.event: dict[str, Any] = {}
        self._backend: PushesBodies | None = None

    def on_start(self, loop: ControlLoop) -> None:
        backend = loop.backend
        if not isinstance(backend, PushesBodies):
            raise ConfigError(
                f"the disturbance protocol needs a backend that can push bodies "
                f"(PushesBodies); {type(backend).__name__} cannot"
            )
        self._backend = backend
        self.start_clock(loop)
        protocol, kind = self.protocol, self.protocol.disturbance
        magnitude = kind.force(self.obj.mass)
        link: str | None = None
        if kind.target == "finger":
            link, direction = self._finger(loop)
        else:
            direction = protocol.direction
        force = magnitude * direction
        start = loop.backend.time + protocol.settle_time
        backend.schedule_push(force, start, kind.duration, link)
        self.event = {
            "kind": protocol.kind,
            "target": link or "object",
            "force": [float(f) for f in force],
            "start": protocol.settle_time,
            "duration": kind.duration,
        }

    def _finger(self, loop: ControlLoop) -> tuple[str, FloatArray]:
        """The link a knock hits and its unit direction (out of the object)."""
        backend = loop.backend
        if not isinstance(backend, HasGroundTruth):
            raise ConfigError(
                f"a knock picks a finger touching the object from the simulator's contacts; "
                f"{type(backend).__name__} has no ground_truth_contacts()"
            )
        contacts = backend.ground_truth_contacts()
        hand = self.hand
        touching = sorted(set(int(i) for i in contacts.link))
        palm = hand.link_index(hand.palm_link) if hand.palm_link in hand.link_names else -1
        tips = [i for i in touching if hand.link_fingertip[i]]
        candidates = tips or [i for i in touching if i != palm]
        if not candidates:
            raise ConfigError(
                f"the knock needs a finger touching {self.obj.name!r} at the start; the grasp "
                f"touches it with {[hand.link_names[i] for i in touching] or 'nothing'}"
            )
        link = candidates[int(self.protocol.pick * len(candidates))]
        normal = contacts.n_world[contacts.link == link].sum(axis=0)
        return hand.link_names[link], normal / np.linalg.norm(normal)

    def on_cycle(self, cycle: Cycle) -> str | None:
        self.phase_index = self.phase_at(cycle.t)
        return None

    def on_end(self, loop: ControlLoop) -> None:
        if self._backend is not None:
            self._backend.clear_pushes()
