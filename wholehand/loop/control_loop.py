"""The control loop: observe, filter, run the active stage, apply, let observers see, advance.

One loop serves simulation, the grasp generator and hardware. Each cycle:

1. reads an :class:`~wholehand.backends.observation.Observation` from the backend and checks it
   (well-formed, and plausible if a :class:`~wholehand.loop.gate.ObservationGate` is given);
2. passes it through the observation filters (what the controller sees: pose error, noise,
   latency and rate, dropouts);
3. runs the active :class:`~wholehand.loop.stage.Stage` on a
   :class:`~wholehand.loop.stage.CycleContext`;
4. applies the stage's command, its torques clamped to the joints' limits, or the last
   feasible one;
5. hands the :class:`Cycle` to every observer (protocol, grasp-loss check, recorder, viewer),
   any of which may end the run;
6. advances the backend to the start of the next period.

Time comes from the backend's clock: the run ends once ``duration`` of backend time has passed,
and on a wall-clock backend a cycle that computes past its period is an overrun, counted with its
size in the :class:`LoopReport`, never silently absorbed.

Nothing raises out of a cycle. An :class:`~wholehand.errors.ObservationError` (an unusable
observation, a joint reading :data:`BROKEN_READING` past its limits, a refusal of the gate)
gives status ``bad_state`` with the reason logged; any other exception in a stage gives
``stage_error`` and is kept with its traceback in the report (``loop.report.errors``). Either
way the last feasible command stays applied. Errors of observers and of the backend itself are
not caught: they are bugs of the set-up, not faults of a grasp.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from wholehand.backends.base import Backend, HasGroundTruth
from wholehand.backends.command import Command
from wholehand.backends.observation import Observation, check_observation, load_observation_check
from wholehand.contacts.base import ContactSet
from wholehand.errors import ConfigError, ObservationError
from wholehand.loop.filters import ObservationFilter
from wholehand.loop.gate import ObservationGate
from wholehand.loop.report import MAX_KEPT_ERRORS, LoopReport, Note, StageError, Transition
from wholehand.loop.stage import END, CycleContext, LoopStatus, Stage, StageOutput, preload_all
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel

log = logging.getLogger(__name__)

BROKEN_READING = 1.0
"""A joint reading this far past its joint's limits [rad or m] is no position the joint can
have (a broken encoder, a unit or mapping error): the cycle is refused (``bad_state``, the last
feasible command kept), with or without the plausibility gate, for as long as it lasts."""

HOLD_WARNING_S = 0.1
"""A hold of the last feasible command this long [s] is logged as a warning, once per hold."""


@dataclass(frozen=True)
class Cycle:
    """Everything one cycle saw and did, for observers."""

    index: int
    """Cycle number since :meth:`ControlLoop.run` started."""
    t: float
    """Backend time at the start of the cycle [s]."""
    truth: Observation
    """The backend's observation, before the filters (simulation: the true state)."""
    context: CycleContext
    """What the stage saw."""
    stage: str
    """Name of the stage that ran."""
    output: StageOutput
    """The stage's output (its status, or the loop's when the cycle faulted)."""
    command: Command
    """The command actually applied (the last feasible one when ``output.command`` is None)."""
    cycle_time: float
    """Compute time from reading the observation to applying the command [s]."""
    fault: str = ""
    """Why the cycle faulted ("" when it did not)."""


class Observer:
    """Sees every cycle after its command is applied; may push the object or end the run."""

    def on_start(self, loop: ControlLoop) -> None:
        """Called once before the first cycle."""

    def on_cycle(self, cycle: Cycle) -> str | None:
        """Called after the cycle's command is applied, before the backend advances. A
        returned string ends the run at once (the backend does not advance); it is the
        reason."""
        return None

    def on_end(self, loop: ControlLoop) -> None:
        """Called once after the last cycle, also when the run stopped early."""


class ControlLoop:
    """Runs stages over a backend at a control rate, on the backend's clock.

    Args:
        backend: the robot or simulation.
        hand: the hand model (kinematics, joint counts).
        obj: the object model.
        stages: the stages by name, or one stage.
        first: the stage active at the start (default: the first one).
        rate: control rate [Hz] (on the backend's clock).
        filters: observation filters, applied in order to what the stages see.
        observers: observers, called in order each cycle.
        initial_command: applied until a stage produces one (default: zero torques).
        gate: a plausibility gate applied to each observation before the filters (None: none).
        compute_delay: simulated real time, on a simulation clock only: a cycle's command takes
            effect once the cycle's compute time as measured on this computer has passed on
            the backend's clock (rounded to its nearest step), the previous command acting
            meanwhile; a cycle that computes past its period pushes the next one back (its
            slot is missed, as on a robot). False: the command takes effect at the cycle's
            start, as if computing took no time.
    """

    def __init__(
        self,
        backend: Backend,
        hand: HandModel,
        obj: ObjectModel,
        stages: Mapping[str, Stage] | Stage,
        first: str | None = None,
        rate: float = 200.0,
        filters: Sequence[ObservationFilter] = (),
        observers: Sequence[Observer] = (),
        initial_command: Command | None = None,
        gate: ObservationGate | None = None,
        compute_delay: bool = False,
    ) -> None:
        if compute_delay and backend.clock != "sim":
            raise ConfigError(
                "ControlLoop: compute_delay simulates the time a cycle computes and needs a "
                "simulation clock; on a wall clock that time passes by itself"
            )
        if not (isinstance(rate, int | float) and 0.0 < rate < np.inf):
            raise ConfigError(f"ControlLoop: rate must be a finite number > 0 [Hz], got {rate!r}")
        self.stages: dict[str, Stage] = (
            {stages.name: stages} if isinstance(stages, Stage) else dict(stages)
        )
        if not self.stages:
            raise ConfigError("ControlLoop: give at least one stage")
        self.active = first if first is not None else next(iter(self.stages))
        if self.active not in self.stages:
            raise ConfigError(
                f"ControlLoop: first stage {self.active!r} is not one of {sorted(self.stages)}"
            )
        self.backend, self.hand, self.obj = backend, hand, obj
        self.rate = float(rate)
        self.dt = 1.0 / self.rate
        self.filters = list(filters)
        self.observers = list(observers)
        self.gate = gate
        self.compute_delay = compute_delay
        self._pending: tuple[Command, float] | None = None
        """With compute_delay: the command of the latest cycle and its compute time [s]."""
        self.command = initial_command or Command.torques(np.zeros(hand.nv))
        """The last feasible command (the one memory of it)."""
        self.report = LoopReport()
        self._tau_max = np.where(hand.actuated_dofs | hand.arm_dofs, hand.tau_max, 0.0)
        self._q_lowest = hand.q_lower - BROKEN_READING
        self._q_highest = hand.q_upper + BROKEN_READING
        self._kin_now = HandKinematics(hand)
        self._kin_then = HandKinematics(hand)
        self._started: set[str] = set()
        self._hold_start: float | None = None  # backend time of the current hold's first cycle
        self._hold_cycles = 0
        self._hold_status = ""
        self._hold_warned = False
        self._preloaded = False
        load_observation_check(hand.nq, hand.nv)  # now rather than in the first cycle

    # --------------------------------------------------------------------------------------------
    def run(self, duration: float | None = None) -> LoopReport:
        """Run until ``duration`` [s] of backend time has passed (None: until a stage ends the run
        or an observer stops it). A cycle runs when at least half a period is left. On a
        simulation clock cycle n starts at ``t0 + n / rate`` rounded up to the backend's step,
        so the rate holds on average whatever the step (at most one cycle per step)."""
        if duration is not None and not (np.isfinite(duration) and duration >= 0.0):
            raise ConfigError(f"ControlLoop.run: duration must be >= 0 [s], got {duration!r}")
        backend = self.backend
        if not self._preloaded:
            self._preloaded = True
            self._preload(backend.time)
        for observer in self.observers:
            observer.on_start(self)
        t0 = backend.time  # after the preload: a process's first loads make no late cycle
        report = self.report
        n_run = 0  # cycles of this run
        deadline = t0  # wall clock: a fixed schedule (sleep overshoot never lowers the rate)
        try:
            while True:
                t = backend.time
                if duration is not None and t - t0 + 0.5 * self.dt >= duration:
                    report.stopped_by = "duration"
                    break
                cycle = self._cycle(report.cycles, t)
                report.cycles += 1
                stop = self._after(cycle)
                if stop is not None:
                    report.stopped_by = stop
                    break
                n_run += 1
                deadline = self._next_cycle(t0, n_run, t, deadline)
        finally:
            for observer in self.observers:
                observer.on_end(self)
        return report

    def _preload(self, t: float) -> None:
        """Once per loop, before its first cycle: :func:`~wholehand.loop.stage.preload_all`
        with the backend's first joint reading (none while it is not a valid one) and the object
        at the world origin: what the controller sees of the object comes through its filters
        (a tracker, a study's pose error), in the cycles."""
        first = self.backend.observe()
        try:
            check_observation(first, self.hand.nq, self.hand.nv)
        except ObservationError:
            return
        first = dataclasses.replace(first, wMo=np.eye(4))
        kin = self._kin_now, self._kin_then
        context = CycleContext(t, self.dt, first, self.hand, self.obj, *kin)
        preload_all(self.stages.values(), context)

    def _after(self, cycle: Cycle) -> str | None:
        """Show the cycle to the observers and switch to the stage it asks for; why the run
        stops (an observer's reason, or the stage's END), or None."""
        reason = None
        for observer in self.observers:
            reason = observer.on_cycle(cycle) or reason
        if reason is not None:
            return reason
        output = cycle.output
        next_stage = output.next
        if next_stage == END:
            return END
        if next_stage is not None:
            self._switch(next_stage, cycle.t, output.reason)
        elif output.reason:
            self._note(cycle.t, output.status, output.reason)
        return None

    def _note(self, t: float, status: str, reason: str) -> None:
        """Keep what the active stage said without switching, unless it said just that last."""
        notes = self.report.notes
        last = notes[-1] if notes else None
        said = last is not None and (last.stage, last.status, last.reason) == (
            self.active,
            status,
            reason,
        )
        if not said:
            notes.append(Note(t, self.active, status, reason))

    def _next_cycle(self, t0: float, n_run: int, t: float, deadline: float) -> float:
        """Advance the backend to the start of the run's cycle ``n_run`` (after the one at
        ``t``); the wall clock's next ``deadline`` (unchanged on a simulation clock)."""
        backend, report = self.backend, self.report
        if backend.clock == "sim":
            start = t + 0.5 * self.dt
            if self._pending is not None:
                start = max(start, self._apply_when_computed(*self._pending))
                self._pending = None
            # The schedule t0 + n dt keeps the rate on average when a period is not a whole
            # number of simulation steps; every cycle advances at least one step.
            self._advance(max(t0 + n_run * self.dt, start))
            return deadline
        deadline += self.dt
        overran = self._advance(deadline)
        late = backend.time - deadline
        if late > self.dt:  # woke a whole period late: a missed slot too
            if not overran:
                report.overruns += 1
                report.max_overrun = max(report.max_overrun, late)
            deadline = backend.time
        return deadline

    def _apply_when_computed(self, command: Command, compute: float) -> float:
        """Let the previous command act for ``compute`` [s] of simulated time (to the nearest
        whole step of the backend, when it says its step), then apply ``command``; the
        backend time at which it took effect."""
        backend = self.backend
        step = getattr(backend, "timestep", None)
        if isinstance(step, float) and step > 0.0:
            compute = round(compute / step) * step
        if compute > 0.0:
            backend.step(compute)
        backend.apply(command)
        return backend.time

    def _switch(self, name: str, t: float, reason: str = "") -> None:
        if name not in self.stages:  # a bug of the stage: reported, and the stage stays
            message = (
                f"ConfigError: stage {self.active!r} switched to {name!r}, which is not one of "
                f"{sorted(self.stages)}"
            )
            self._keep_error(t, self.active, message, None)
            return
        self.report.transitions.append(Transition(t, self.active, name, reason))
        self.active = name
        self._started.discard(name)

    def _advance(self, t_next: float) -> bool:
        """Advance the backend to ``t_next``; True when a wall clock had already passed it."""
        backend = self.backend
        left = t_next - backend.time
        overran = backend.clock == "wall" and left < 0.0
        if overran:
            self.report.overruns += 1
            self.report.max_overrun = max(self.report.max_overrun, -left)
        backend.step(max(left, 0.0))
        return overran

    # --------------------------------------------------------------------------------------------
    def _cycle(self, index: int, t: float) -> Cycle:
        started = time.perf_counter()
        truth = self.backend.observe()
        stage = self.stages[self.active]
        output, fault, context = self._step(stage, truth, t)
        if context is None:  # the cycle failed before its context was built
            context = CycleContext(
                t, self.dt, truth, self.hand, self.obj, self._kin_now, self._kin_then
            )
        if output.command is not None:
            self.command = output.command
            self._hold_start = None
        else:
            self._held(t, output.status)
        if self.compute_delay:
            self._pending = (self.command, time.perf_counter() - started)
        else:
            self.backend.apply(self.command)
        self._count(output.status, fault, t)
        return Cycle(
            index,
            t,
            truth,
            context,
            stage.name,
            output,
            self.command,
            time.perf_counter() - started,
            fault,
        )

    def _step(
        self, stage: Stage, truth: Observation, t: float
    ) -> tuple[StageOutput, str, CycleContext | None]:
        """Check the reading, filter it and step the stage; its output, the fault ("" if
        none) and the cycle's context (None if the cycle failed before it was built). Never
        raises: a bad reading or a stage's exception becomes a status without a command."""
        obs = truth
        context: CycleContext | None = None
        try:
            check_observation(truth, self.hand.nq, self.hand.nv)
            self._check_joint_range(truth.q)
            if self.gate is not None:
                self.gate.check(truth)
            for f in self.filters:
                obs = f.apply(obs, t)
            context = CycleContext(
                t,
                self.dt,
                obs,
                self.hand,
                self.obj,
                self._kin_now,
                self._kin_then,
                self._ground_truth(truth, obs),
            )
            if obs.wMo is None and stage.needs_object_pose:
                output = StageOutput(None, LoopStatus.NO_POSE.value)
                return output, "no object pose has arrived yet", context
            if self.active not in self._started:
                self._started.add(self.active)
                stage.start(context)
            output = stage.step(context)
            if output.command is not None:
                checked = self._checked(output.command)
                if checked is not output.command:
                    output = dataclasses.replace(output, command=checked)
            return output, "", context
        except ObservationError as err:
            return StageOutput(None, LoopStatus.BAD_STATE.value), str(err), context
        except Exception as err:  # noqa: BLE001 - the loop never raises mid-grasp
            fault = f"{type(err).__name__}: {err}"
            self._keep_error(t, stage.name, fault, err)
            return StageOutput(None, LoopStatus.STAGE_ERROR.value), fault, context

    def _count(self, status: str, fault: str, t: float) -> None:
        """Count the cycle's status, and its fault if any (logged when it is a new one)."""
        report = self.report
        report.status_counts[status] += 1
        if fault:
            report.faults[status] += 1
            if fault != report.last_fault:
                log.info("cycle at t = %.4f s: %s (%s)", t, status, fault)
            report.last_fault = fault

    def _check_joint_range(self, q: np.ndarray) -> None:
        """Raise :class:`ObservationError` for a joint reading :data:`BROKEN_READING` or more
        past its limits."""
        lowest, highest = self._q_lowest, self._q_highest
        if (q >= lowest).all() and (q <= highest).all():
            return
        i = int(np.flatnonzero((q < lowest) | (q > highest))[0])
        hand = self.hand
        name = next(
            (n for n in hand.joint_names if hand.model.joints[hand.model.getJointId(n)].idx_q == i),
            f"q[{i}]",
        )
        raise ObservationError(
            f"joint {name!r} reads {q[i]:.4g}, more than {BROKEN_READING} past its limits "
            f"[{hand.q_lower[i]:.4g}, {hand.q_upper[i]:.4g}]: not a position it can have "
            "(a broken encoder, a unit or mapping error)"
        )

    def _held(self, t: float, status: str) -> None:
        """Count a cycle that keeps the last feasible command, and the hold it belongs to."""
        report = self.report
        report.held_commands += 1
        if self._hold_start is None:
            self._hold_start, self._hold_cycles = t, 0
            self._hold_status, self._hold_warned = status, False
        self._hold_cycles += 1
        length = t - self._hold_start + self.dt
        if self._hold_cycles > report.longest_hold:
            report.longest_hold, report.longest_hold_s = self._hold_cycles, length
            report.longest_hold_at, report.longest_hold_status = self._hold_start, self._hold_status
        if length >= HOLD_WARNING_S and not self._hold_warned:
            self._hold_warned = True
            log.warning(
                "the last feasible command has been held for %.3f s since t = %.4f s (%s first)",
                length,
                self._hold_start,
                self._hold_status,
            )

    def _checked(self, command: Command) -> Command:
        """The command with its torques within the hand's limits (0 on joints without a
        motor); the excess is counted, never sent.

        Raises:
            ConfigError: torques of the wrong shape or not finite (a bug of the stage).
        """
        tau, limit = command.tau, self._tau_max
        # NaN or inf in tau makes the excess NaN or +inf: one reduction checks both.
        excess = float((np.abs(tau) - limit).max()) if tau.shape == limit.shape else math.nan
        if math.isnan(excess) or excess == math.inf:
            what = f"of shape {tau.shape}" if tau.shape != limit.shape else "with NaN or inf"
            raise ConfigError(
                f"stage {self.active!r} commanded torques {what}; the hand needs "
                f"({limit.shape[0]},) finite values [N*m]"
            )
        if excess <= 0.0:
            return command
        self.report.clamped += 1
        self.report.max_excess = max(self.report.max_excess, excess)
        return dataclasses.replace(command, tau=np.clip(tau, -limit, limit))

    def _keep_error(
        self, t: float, stage: str, error: str, exception: BaseException | None
    ) -> None:
        report = self.report
        report.n_errors += 1
        if len(report.errors) < MAX_KEPT_ERRORS:  # the traceback only of those kept (~1 ms)
            trace = "" if exception is None else "".join(traceback.format_exception(exception))
            report.errors.append(StageError(t, stage, error, trace))
        if report.n_errors == 1:
            log.error("stage %r raised at t = %.4f s: %s", stage, t, error)

    def _ground_truth(
        self, truth: Observation, seen: Observation
    ) -> Callable[[], ContactSet] | None:
        """The simulator's contacts, moved rigidly with the error between the true object pose
        and the one the controller sees (so a baseline's one-off allocation uses the ground-truth
        contacts where it believes the object is)."""
        backend = self.backend
        if not isinstance(backend, HasGroundTruth):
            return None
        hand = self.hand

        def contacts() -> ContactSet:  # the error transform only when asked (rarely: at start)
            found = backend.ground_truth_contacts().to_contact_set(hand)
            if seen.wMo is None or truth.wMo is None or seen.wMo is truth.wMo:
                return found
            return found.transformed(seen.wMo @ np.linalg.inv(truth.wMo))

        return contacts
