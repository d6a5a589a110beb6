"""The person of a reach episode: a spring-damper on the object that holds it out (or slides
it on the table), pushes and twists it while the hand holds it, and snatches it away (see
:mod:`wholehand.reaching.episode` for the script and :class:`~wholehand.reaching.episode.
EpisodeSpec` for its parameters)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand import defaults
from wholehand.loop.control_loop import ControlLoop, Cycle, Observer
from wholehand.reaching.stages import REGULATE

if TYPE_CHECKING:
    from wholehand.models.hand import HandModel
    from wholehand.reaching.episode_spec import EpisodeSpec

FloatArray = npt.NDArray[np.float64]

PERSON_BANDWIDTH = 50.0
"""Natural frequency of the person's grip on the object [rad/s]: stiffness ``m w^2`` (``I w^2``
about the axes), critically damped, so that light and heavy objects follow alike and the
explicitly applied spring stays stable (``2 w dt`` well below 2 at 1 ms steps)."""
GAP = 1.0
"""Pause between successive perturbations [s]."""
SNATCH_BANDWIDTH = 150.0
"""The snatch's grip [rad/s]: three times stiffer than the holding grip, so it pulls any of the
paper's objects out of a 0.2 N*m hand (the pull at 15 cm is 0.15 m * m * w^2: 170 N for 50 g);
``2 w dt`` = 0.3 keeps the explicit spring stable."""
PICKUP_SPEED = 1.0
"""How fast the person carries a dropped object to where it is held out [m/s]."""
SNATCH_GIVE_UP = 2.0
"""If the hand still holds the object this long after the snatch, the person lets go [s]."""
SLIDE_TIME = 0.5
"""On a table: how long the person pushes the object to its new place before leaving it [s]."""
PERTURBATIONS = ("person moves", "push", "twist", "person snatches")
"""Events that count as perturbations."""
SKIPPED = ("no push", "no twist")
"""Events of a perturbation left out because the hand held no object: the episode is then not
complete (:attr:`Person.complete`)."""


def grip(
    backend: Any, wMo: FloatArray, mass_inertia: tuple[float, float], w: float = PERSON_BANDWIDTH
) -> None:
    """The person's hand on the object: a critically damped spring-damper toward ``wMo`` with
    natural frequency ``w`` [rad/s] for an object of ``mass_inertia`` ([kg], [kg*m^2])."""
    mass, inertia = mass_inertia
    stiffness = (mass * w**2, inertia * w**2)
    damping = (2.0 * mass * w, 2.0 * inertia * w)
    backend.set_object_spring(wMo, stiffness, damping)


@dataclass
class Event:
    t: float
    what: str


@dataclass
class Person(Observer):
    """Scripts the perturbations of :class:`EpisodeSpec` on a backend that pushes objects."""

    spec: EpisodeSpec
    backend: Any
    wMo_hold: FloatArray
    rng: np.random.Generator
    mass_inertia: tuple[float, float]
    """Object mass [kg] and its largest principal moment of inertia [kg*m^2]."""
    palm_link: str
    rim: float
    """Half the object's largest side [m] (the twist's lever)."""
    on_table: bool = False
    """The object rests on the table: the person slides it and puts it down instead of holding
    it out (:attr:`EpisodeSpec.start`)."""
    holds: Callable[[Cycle], bool] | None = None
    """Whether the hand holds the object in a cycle, as the person sees it (None: the loop's
    stage is ``regulate``; the robot double, which cannot see the controller's stage, judges by
    the simulated contacts)."""
    events: list[Event] = field(default_factory=list)
    state: str = "holding"
    since: float = 0.0
    held_since: float | None = None
    done: bool = False
    _pickup: tuple[FloatArray, FloatArray, float] | None = None
    """A pick-up under way: (object pose at its start, pose to hold it out at, start time)."""

    STEPS: ClassVar[dict[str, str]] = {
        "holding": "_move",
        "moved": "_leave_after_move",
        "resting": "_wait_for_the_grasp",
        "released": "_push",
        "pushing": "_end_push",
        "pushed": "_twist",
        "twisting": "_end_twist",
        "twisted": "_snatch",
        "snatched": "_leave_after_snatch",
        "put down": "_wait_for_the_end",
        "regrasped": "_wait_for_the_end",
    }
    """The script's states, in order, and the method that steps out of each."""

    def on_start(self, loop: ControlLoop) -> None:
        if not self.on_table:
            self._grip(self.wMo_hold)

    def _grip(self, wMo: FloatArray, w: float = PERSON_BANDWIDTH) -> None:
        grip(self.backend, wMo, self.mass_inertia, w)

    def _note(self, t: float, what: str) -> None:
        self.events.append(Event(round(t, 4), what))

    def _horizontal(self) -> FloatArray:
        angle = self.rng.uniform(0.0, 2.0 * np.pi)
        return np.array([np.cos(angle), np.sin(angle), 0.0])

    def _carry(self, t: float) -> None:
        """Move the grip's target of a pick-up toward its goal at :data:`PICKUP_SPEED`."""
        assert self._pickup is not None
        start, goal, t0 = self._pickup
        distance = float(np.linalg.norm(goal[:3, 3] - start[:3, 3]))
        s = min(1.0, (t - t0) * PICKUP_SPEED / max(distance, 1e-9))
        target = goal.copy()
        target[:3, 3] = start[:3, 3] + s * (goal[:3, 3] - start[:3, 3])
        self._grip(target)
        if s >= 1.0:
            self._pickup = None

    def on_cycle(self, cycle: Cycle) -> str | None:
        t = cycle.t
        if self._pickup is not None and self.state == "snatched":  # until the person lets go
            self._carry(t)
        holding = self._holding(cycle)
        self.held_since = (self.held_since or t) if holding else None
        held_for = t - self.held_since if self.held_since is not None else 0.0
        return self._next_step(self.state)(cycle, holding, held_for)

    def _next_step(self, state: str) -> Callable[[Cycle, bool, float], str | None]:
        """The script's step from ``state``: called every cycle with whether the hand holds
        the object and for how long [s]; the episode's end message, or None."""
        step: Callable[[Cycle, bool, float], str | None] = getattr(self, self.STEPS[state])
        return step

    def _to(self, state: str, t: float, note: str | None = None) -> None:
        if note is not None:
            self._note(t, note)
        self.state, self.since = state, t

    def _move(self, cycle: Cycle, holding: bool, held_for: float) -> None:
        """While the hand reaches: move the object by ``displace`` and turn it by 20 deg."""
        t, spec = cycle.t, self.spec
        if t < spec.displace_at:
            return
        assert cycle.truth.wMo is not None  # the episode's backend always has the pose
        target = (cycle.truth.wMo if self.on_table else self.wMo_hold).copy()
        target[:3, 3] += spec.displace * self._horizontal()
        target[:3, :3] = pin.exp3(np.array([0.0, 0.0, np.radians(20.0)])) @ target[:3, :3]
        self._grip(target)
        self._to("moved", t, f"person moves the object by {100 * spec.displace:.0f} cm and 20 deg")

    def _leave_after_move(self, cycle: Cycle, holding: bool, held_for: float) -> None:
        """On a table, leave the moved object there; in the air, let go once the hand has
        held it for ``release_after``."""
        t = cycle.t
        if self.on_table and t - self.since >= SLIDE_TIME:
            self.backend.set_object_spring(None)
            self._to("resting", t, "person leaves the object on the table")
        elif not self.on_table and held_for >= self.spec.release_after:
            self.backend.set_object_spring(None)
            self._to("released", t, "person lets go")

    def _wait_for_the_grasp(self, cycle: Cycle, holding: bool, held_for: float) -> None:
        if held_for >= self.spec.release_after:
            self._to("released", cycle.t)  # held off the table's support: pushes next

    def _push(self, cycle: Cycle, holding: bool, held_for: float) -> None:
        # Pushes and twists test a grip: an object the hand has dropped is left alone (a
        # 0.1 N*m twist on a dropped Lego brick spun it at 1000 rad/s).
        t, spec = cycle.t, self.spec
        if t - self.since < GAP:
            return
        push = spec.push * self.mass_inertia[0] * defaults.GRAVITY
        if holding:
            self.backend.apply_object_wrench(push * self._horizontal(), np.zeros(3))
            self._to("pushing", t, f"push {push:.2f} N for {spec.pulse} s")
        else:
            self._to("pushed", t, "no push: the hand holds no object")

    def _end_push(self, cycle: Cycle, holding: bool, held_for: float) -> None:
        if cycle.t - self.since >= self.spec.pulse or not holding:
            self.backend.apply_object_wrench(np.zeros(3), np.zeros(3))
            self._to("pushed", cycle.t)

    def _twist(self, cycle: Cycle, holding: bool, held_for: float) -> None:
        t, spec = cycle.t, self.spec
        if t - self.since < GAP:
            return
        axis = self.rng.normal(size=3)
        twist = spec.twist * self.mass_inertia[0] * defaults.GRAVITY * self.rim
        if holding:
            self.backend.apply_object_wrench(np.zeros(3), twist * axis / np.linalg.norm(axis))
            self._to("twisting", t, f"twist {twist:.3f} N*m for {spec.pulse} s")
        else:
            self._to("twisted", t, "no twist: the hand holds no object")

    def _end_twist(self, cycle: Cycle, holding: bool, held_for: float) -> None:
        if cycle.t - self.since >= self.spec.pulse or not holding:
            self.backend.apply_object_wrench(np.zeros(3), np.zeros(3))
            self._to("twisted", cycle.t)

    def _snatch(self, cycle: Cycle, holding: bool, held_for: float) -> None:
        if cycle.t - self.since < GAP:
            return
        if self.on_table:
            self._snatch_on_table(cycle)
        else:
            self._snatch_in_the_air(cycle, holding)

    def _leave_after_snatch(self, cycle: Cycle, holding: bool, held_for: float) -> None:
        """On a table, leave the snatched object where it was pulled to; in the air, let go
        once the hand has regrasped it for ``release_after`` (or kept it through the snatch
        for :data:`SNATCH_GIVE_UP`)."""
        t = cycle.t
        if self.on_table:
            if t - self.since >= SLIDE_TIME:
                self.backend.set_object_spring(None)
                self._to("put down", t, "person leaves the object on the table")
            return
        if held_for < self.spec.release_after or self.held_since is None:
            return
        if self.held_since > self.since:  # a grasp made after the snatch
            self.backend.set_object_spring(None)
            self._to("regrasped", t, "person lets go")
        elif t - self.since >= SNATCH_GIVE_UP:
            self.backend.set_object_spring(None)
            self._to("regrasped", t, "person lets go: the hand kept the object through the snatch")

    @property
    def skipped(self) -> list[str]:
        """The perturbations left out because the hand held no object (their events)."""
        return [e.what for e in self.events if e.what.startswith(SKIPPED)]

    @property
    def complete(self) -> bool:
        """The episode's script ran to its end: every perturbation met a held object, and after
        the person last let go the hand held the object for ``hold_after``."""
        return self.done and not self.skipped

    def _wait_for_the_end(self, cycle: Cycle, holding: bool, held_for: float) -> str | None:
        """Complete once the hand has held the object for ``hold_after`` since the person let
        go (or left it on the table), not since the grasp was made."""
        if holding and min(held_for, cycle.t - self.since) >= self.spec.hold_after:
            self.done = True
            return "episode complete"
        return None

    def _snatch_in_the_air(self, cycle: Cycle, holding: bool) -> None:
        """Pull a held object ``snatch`` away from the palm; pick a dropped one up and hold it
        out beside where it was first held."""
        t, spec = cycle.t, self.spec
        assert cycle.truth.wMo is not None  # the episode's backend always has the pose
        target = cycle.truth.wMo.copy()
        if holding:  # pulled out of the hand, away from the palm (a pull
            # into the palm would be held by the wrist, not the grip), not downward
            target[:3, 3] += spec.snatch * self._away_from_palm(cycle, target, upward=True)
            target[2, 3] = max(target[2, 3], self.wMo_hold[2, 3])
            self._grip(target, SNATCH_BANDWIDTH)
            self._to("snatched", t, f"person snatches the object {100 * spec.snatch:.0f} cm away")
        else:  # dropped earlier: picked up and held out beside where it was first held,
            # the grip's target carried there at PICKUP_SPEED (a spring stretched to an
            # object flung off the table yanked it to 300 m/s)
            goal = target.copy()
            goal[:3, 3] = self.wMo_hold[:3, 3] + spec.snatch * self._horizontal()
            self._pickup = (target, goal, t)
            self._carry(t)
            self._to("snatched", t, "person picks the dropped object up and holds it out")

    def _holding(self, cycle: Cycle) -> bool:
        return cycle.stage == REGULATE if self.holds is None else self.holds(cycle)

    def _away_from_palm(self, cycle: Cycle, wMo: FloatArray, upward: bool) -> FloatArray:
        """(3,) unit direction of a snatch: from the palm to the object at ``wMo``, never
        downward (``upward``: its upward part kept) or horizontal (else); a random horizontal
        one when the object sits on the palm's centre."""
        palm = cycle.context.kinematics.frame_pose(self.palm_link)[:3, 3]
        away = wMo[:3, 3] - palm
        away[2] = max(away[2], 0.0) if upward else 0.0
        norm = float(np.linalg.norm(away))
        return away / norm if norm > 1e-6 else self._horizontal()

    def _snatch_on_table(self, cycle: Cycle) -> None:
        """On a table: pull the object along the table, away from the palm, by ``snatch`` plus
        its largest side (so that it leaves the hand however large it is), and put it down
        there (:data:`SLIDE_TIME` later); the hand must regrasp it where it lies."""
        t, spec = cycle.t, self.spec
        if self._holding(cycle):
            assert cycle.truth.wMo is not None
            target = cycle.truth.wMo.copy()
            distance = spec.snatch + 2.0 * self.rim
            target[:3, 3] += distance * self._away_from_palm(cycle, target, upward=False)
            self._grip(target, SNATCH_BANDWIDTH)
            self._note(t, f"person snatches the object {100 * distance:.0f} cm along the table")
        else:
            self._note(t, "no snatch: the hand holds no object")
        self.state, self.since = "snatched", t


CAUSES = {
    "person lets go": "gravity",
    "push": "push",
    "twist": "twist",
    "person snatches": "snatch",
    "person moves": "move",
    "person picks": "pickup",
}
"""Event text prefix -> the cause a loss after it is put down to."""


def loss_cause(events: list[Event], t: float) -> str:
    """The kind of the latest event before ``t`` [s] ("none" if there was none)."""
    before = [e for e in events if e.t <= t]
    if not before:
        return "none"
    what = before[-1].what
    return next((cause for prefix, cause in CAUSES.items() if what.startswith(prefix)), "other")


HOLD_MEMORY = 0.25
"""The person believes the hand holds the object for this long [s] after the thumb and two
other fingers last touched it together (contacts flicker while a grasp is regulated)."""


class ContactHolds:
    """The person's view of a grasp: the thumb and two other fingers touched the object in the
    simulation within the last :data:`HOLD_MEMORY` (checked once per cycle; MuJoCo's forward
    pass gives the contacts)."""

    def __init__(self, hand: HandModel, backend: Any) -> None:
        self.backend = backend
        finger_of = {}
        for finger, links in hand.config.fingers.items():
            for link in links:
                if link in hand.link_names:
                    finger_of[hand.link_index(link)] = finger
        self.finger_of, self.thumb = finger_of, hand.config.thumb
        self._checked = -np.inf
        self._touched = -np.inf

    def __call__(self, cycle: Cycle) -> bool:
        if self._checked != cycle.t:
            self._checked = cycle.t
            touching = {
                self.finger_of[int(i)]
                for i in self.backend.ground_truth_contacts().link
                if int(i) in self.finger_of
            }
            if self.thumb in touching and len(touching - {self.thumb}) >= 2:
                self._touched = cycle.t
        return cycle.t - self._touched <= HOLD_MEMORY
