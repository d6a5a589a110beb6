"""``wholehand bench soak``: a held grasp for many cycles with a fault injected every ``every``.

The faults come in turn from :data:`FAULTS`, one cycle each, where a real system meets them: in
the backend's observation (a sensor or tracker glitch), in the contact estimator, in the
allocator. Between faults the grasp is held by the paper's controller (``mesh_sdf`` + ``qp``,
gravity off). What must hold, and what the report counts:

- no exception leaves the control loop (``exceptions``);
- no applied torque exceeds a joint's limit (``torque_limit_violations``);
- every fault is followed by a fresh feasible torque (status ``ok`` or ``unbalanced``) within
  a few cycles
  (``recovered`` of ``injected``, and the most cycles it took);
- the grasp is still held at the end;
- memory stays flat (resident set size after the first tenth of the run and at its end).
"""

from __future__ import annotations

import resource
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from wholehand.allocation.base import FRESH_STATUSES, Allocation, AllocationStatus, Allocator
from wholehand.backends.base import Backend
from wholehand.backends.command import Command
from wholehand.backends.observation import Observation
from wholehand.contacts.base import ContactEstimator, ContactSet
from wholehand.errors import ConfigError
from wholehand.loop.control_loop import ControlLoop, Cycle, Observer
from wholehand.loop.gate import ObservationGate
from wholehand.loop.grasp_loss import GraspLossMonitor
from wholehand.provenance import provenance
from wholehand.timing import percentiles_us
from wholehand.trials.trial import TrialSpec, set_up_trial

FloatArray = npt.NDArray[np.float64]


def _obs(obs: Observation, **changes: Any) -> Observation:
    return replace(obs, **changes)


def _moved(obs: Observation, shift: FloatArray) -> Observation:
    wMo = obs.wMo.copy() if obs.wMo is not None else np.eye(4)
    wMo[:3, 3] += shift
    return obs.with_object(wMo, obs.stamp_object)


def _pose(obs: Observation) -> FloatArray:
    assert obs.wMo is not None  # the soak's simulation always has the pose
    return obs.wMo


def _q(obs: Observation, i: int, value: Any) -> Observation:
    q = obs.q.astype(object if isinstance(value, str) else float)
    q[i] = value
    return _obs(obs, q=q)


OBSERVATION_FAULTS: dict[str, Callable[[Observation], Observation]] = {
    "q_nan": lambda o: _q(o, 3, np.nan),
    "q_inf": lambda o: _q(o, 0, np.inf),
    "q_short": lambda o: _obs(o, q=o.q[:-1]),
    "q_text": lambda o: _q(o, 2, "1.0"),
    "q_beyond_limits": lambda o: _q(o, 5, 40.0),
    "dq_nan": lambda o: _obs(o, dq=np.full_like(o.dq, np.nan)),
    "pose_nan": lambda o: _moved(o, np.array([np.nan, 0.0, 0.0])),
    "pose_not_rigid": lambda o: o.with_object(2.0 * _pose(o), o.stamp_object),
    "pose_far": lambda o: _moved(o, np.array([10.0, 0.0, 0.0])),
    "pose_jump": lambda o: _moved(o, np.array([0.0, 0.05, 0.0])),
    "pose_missing": lambda o: o.with_object(None, o.stamp_object),
    "pose_wrong_shape": lambda o: o.with_object(_pose(o)[:3], o.stamp_object),
    "base_not_rigid": lambda o: _obs(o, wMb=2.0 * o.wMb),
}
"""Corrupted or impossible readings, as a backend delivers them."""

ESTIMATOR_FAULTS = ("estimator_raises", "normals_zero", "normals_nan", "contacts_empty")
"""The contact estimator raises, or returns contacts with zero or NaN normals, or none."""
ALLOCATOR_FAULTS = (
    "allocator_raises",
    "tau_nan",
    "tau_wrong_shape",
    "tau_over_limit",
    "solver_failed",
)
"""The allocator raises, returns NaN torques, torques of the wrong length, torques ten times the
limit, or reports a failed solve."""

FAULTS: tuple[str, ...] = (*OBSERVATION_FAULTS, *ESTIMATOR_FAULTS, *ALLOCATOR_FAULTS)

FRESH = frozenset(s.value for s in FRESH_STATUSES)
"""Cycle statuses of a fresh feasible torque: a fault counts as recovered at the first."""
"""Every fault kind, in the order they are injected."""


@dataclass
class FaultSchedule:
    """Which fault, if any, the cycle counted by :meth:`tick` gets: every ``every``-th cycle
    (from cycle ``every``) the next kind of ``kinds``."""

    every: int
    kinds: tuple[str, ...] = FAULTS
    cycle: int = -1
    current: str = ""
    injected: Counter[str] = field(default_factory=Counter)

    def tick(self) -> str:
        self.cycle += 1
        n = self.cycle // self.every
        due = n > 0 and self.cycle % self.every == 0
        self.current = self.kinds[(n - 1) % len(self.kinds)] if due else ""
        if self.current:
            self.injected[self.current] += 1
        return self.current


class FaultyBackend(Backend):
    """A backend whose observations get the schedule's observation faults (the schedule ticks
    here, once per cycle: on the first observation at each backend time, since the loop also
    observes once before its first cycle, to preload)."""

    def __init__(self, backend: Backend, schedule: FaultSchedule) -> None:
        self.backend, self.schedule = backend, schedule
        self._ticked_at = float("nan")

    def observe(self) -> Observation:
        obs = self.backend.observe()
        if self.backend.time != self._ticked_at:
            self._ticked_at = self.backend.time
            self.schedule.tick()
        fault = self.schedule.current
        return OBSERVATION_FAULTS[fault](obs) if fault in OBSERVATION_FAULTS else obs

    def apply(self, command: Command) -> None:
        self.backend.apply(command)

    def step(self, duration: float) -> None:
        self.backend.step(duration)

    @property
    def time(self) -> float:
        return self.backend.time

    def ground_truth_contacts(self) -> Any:
        return self.backend.ground_truth_contacts()  # type: ignore[attr-defined]


class FaultyEstimator(ContactEstimator):
    """Wraps an estimator; misbehaves on the schedule's estimator faults."""

    def __init__(self, inner: ContactEstimator, schedule: FaultSchedule) -> None:
        self.inner, self.schedule = inner, schedule

    def estimate(self, kinematics: Any, wMo: FloatArray, stamp: float = 0.0) -> ContactSet:
        fault = self.schedule.current
        if fault == "estimator_raises":
            raise ValueError("injected: the estimator failed")
        contacts = self.inner.estimate(kinematics, wMo, stamp=stamp)
        if fault == "contacts_empty":
            return contacts.select(np.zeros(len(contacts), dtype=bool))
        if fault in ("normals_zero", "normals_nan"):
            zero = fault == "normals_zero"
            return replace(contacts, n_world=contacts.n_world * (0.0 if zero else np.nan))
        return contacts


class FaultyAllocator(Allocator):
    """Wraps an allocator; misbehaves on the schedule's allocator faults."""

    def __init__(self, inner: Allocator, schedule: FaultSchedule) -> None:
        self.inner, self.schedule = inner, schedule
        self.needs_ground_truth = inner.needs_ground_truth  # type: ignore[misc]

    def start(self, context: Any) -> None:
        self.inner.start(context)

    def reset(self) -> None:
        self.inner.reset()

    def allocate(
        self,
        contacts: ContactSet,
        J_world: FloatArray,
        p_com_world: FloatArray,
        kinematics: Any = None,
    ) -> Allocation:
        fault = self.schedule.current
        if fault == "allocator_raises":
            raise np.linalg.LinAlgError("injected: singular matrix while building the QP")
        allocation = self.inner.allocate(contacts, J_world, p_com_world, kinematics)
        if allocation.tau is None or fault not in ALLOCATOR_FAULTS:
            return allocation
        tau = allocation.tau
        changed = {
            "tau_nan": np.full_like(tau, np.nan),
            "tau_wrong_shape": tau[:-1],
            "tau_over_limit": 10.0 * np.sign(tau + 1e-12),
            "solver_failed": None,
        }[fault]
        status = AllocationStatus.SOLVER_FAILED if fault == "solver_failed" else allocation.status
        return replace(allocation, tau=changed, status=status)


def _rss_mb() -> float:
    """Resident set size of this process [MB] (Linux /proc; else the peak from getrusage)."""
    statm = Path("/proc/self/statm")
    if statm.is_file():
        pages = int(statm.read_text().split()[1])
        return pages * resource.getpagesize() / 1e6
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3


class SoakMonitor(Observer):
    """Counts torque-limit violations, recoveries and memory over the run."""

    def __init__(self, tau_max: FloatArray, schedule: FaultSchedule, cycles: int) -> None:
        self.tau_max, self.schedule, self.cycles = tau_max, schedule, cycles
        self.violations = 0
        self.recovered = 0
        self.worst_recovery = 0
        self._since_fault: int | None = None
        self.rss_mb: dict[str, float] = {}
        self.cycle_times = np.zeros(cycles)
        """Compute time of each cycle [s] (preallocated: the soak measures memory growth)."""

    def on_cycle(self, cycle: Cycle) -> str | None:
        if np.any(np.abs(cycle.command.tau) > self.tau_max + 1e-12):
            self.violations += 1
        if cycle.index < self.cycle_times.size:
            self.cycle_times[cycle.index] = cycle.cycle_time
        if self.schedule.current:
            self._since_fault = 0
        elif self._since_fault is not None:
            self._since_fault += 1
            if cycle.output.status in FRESH:
                self.recovered += 1
                self.worst_recovery = max(self.worst_recovery, self._since_fault)
                self._since_fault = None
        if cycle.index == self.cycles // 10:
            self.rss_mb["after_first_tenth"] = round(_rss_mb(), 1)
        elif cycle.index == self.cycles // 2:
            self.rss_mb["half_way"] = round(_rss_mb(), 1)
        return None


def run_soak(
    cycles: int = 100_000,
    every: int = 100,
    hand: str = "allegro_right",
    obj: str = "077_rubiks_cube",
    grasp: int = 0,
    rate: float = 200.0,
) -> dict[str, object]:
    """Hold ``grasp`` for ``cycles`` control cycles at ``rate`` [Hz] of simulation time with one
    fault every ``every`` cycles; the report (JSON-able) described in the module docstring."""
    if cycles < 1 or every < 2:
        raise ConfigError(f"soak: cycles must be >= 1 and every >= 2, got {cycles}, {every}")
    schedule = FaultSchedule(every)
    trial = set_up_trial(TrialSpec(hand=hand, object=obj, grasp=grasp))
    regulation = trial.regulation
    regulation.estimator = FaultyEstimator(regulation.estimator, schedule)
    regulation.allocator = FaultyAllocator(regulation.allocator, schedule)
    monitor = SoakMonitor(
        np.where(trial.hand.actuated_dofs, trial.hand.tau_max, 0.0), schedule, cycles
    )
    loss = GraspLossMonitor(trial.hand, trial.obj, stop_on_loss=False)
    loop = ControlLoop(
        FaultyBackend(trial.backend, schedule),
        trial.hand,
        trial.obj,
        regulation,
        rate=rate,
        observers=[loss, monitor],
        gate=ObservationGate(trial.hand),
    )
    exceptions: list[str] = []
    started = time.perf_counter()
    try:
        loop.run(cycles / rate)  # cycle k runs at k / rate: cycles 0 .. cycles - 1
    except Exception as err:  # noqa: BLE001 - counted: the soak's first requirement
        exceptions.append(f"{type(err).__name__}: {err}")
    wall = time.perf_counter() - started
    report = loop.report
    injected = sum(schedule.injected.values())
    return {
        "benchmark": "soak",
        "hand": trial.hand.name,
        "object": trial.obj.name,
        "grasp": grasp,
        "cycles": report.cycles,
        "fault_every": every,
        "fault_kinds": len(FAULTS),
        "injected": dict(schedule.injected),
        "n_injected": injected,
        "exceptions": len(exceptions),
        "exception_messages": exceptions[:3],
        "torque_limit_violations": monitor.violations,
        "recovered": monitor.recovered,
        "most_cycles_to_recover": monitor.worst_recovery,
        "held_at_end": loss.held,
        "lost_at_s": loss.lost_at,
        "loop": {
            "faults": dict(report.faults),
            "status_counts": dict(report.status_counts),
            "stage_errors": report.n_errors,
            "clamped": report.clamped,
            "held_commands": report.held_commands,
            "longest_hold": report.longest_hold,
            "gate_refused": dict(loop.gate.refused) if loop.gate else {},
        },
        "memory_mb": {**monitor.rss_mb, "at_end": round(_rss_mb(), 1)},
        "cycle": percentiles_us(monitor.cycle_times[: report.cycles] * 1e9),
        "wall_time_s": round(wall, 1),
        "machine": provenance(),
    }
