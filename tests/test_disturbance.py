"""Fast disturbances: pushes scheduled at the simulation's steps (against the impulse they must
give), the protocol and its driver, the loop's simulated compute time on a clock the test
moves, and the study's design and summary."""

from __future__ import annotations

import types

import numpy as np
import pytest

from wholehand import registry
from wholehand.backends import Backend
from wholehand.backends.command import Command
from wholehand.backends.observation import Observation
from wholehand.errors import ConfigError
from wholehand.grasps.store import load_grasps
from wholehand.loop import control_loop
from wholehand.loop.control_loop import ControlLoop
from wholehand.loop.stage import Stage, StageOutput
from wholehand.models.object_catalogue import load_object
from wholehand.studies import get_study
from wholehand.studies.disturbance import CONFIGS, TAILS
from wholehand.trials.disturbance import DISTURBANCES, DisturbanceProtocol
from wholehand.trials.outcome import outcome_of
from wholehand.trials.trial import TrialSpec, run_trial

CUBE = "077_rubiks_cube"
TINY = {"settle_time": 0.1, "recovery_time": 0.1}


@pytest.fixture(scope="module")
def cube():
    return load_object(CUBE)


def free_object(allegro, cube):
    """The cube 1 m above the hand, no gravity: nothing touches it."""
    wMo = np.eye(4)
    wMo[:3, 3] = [0.0, 0.0, 1.0]
    return registry.load("backends", "mujoco", hand=allegro, obj=cube, wMo_init=wMo)


def test_a_push_gives_the_impulse_of_its_window(allegro, cube):
    sim = free_object(allegro, cube)
    force = np.array([0.3, -0.2, 0.5])
    sim.schedule_push(force, start=0.005, duration=0.020)
    sim.step(0.004)  # before the window
    np.testing.assert_allclose(sim.object_velocity()[0], 0.0, atol=1e-12)
    sim.step(0.040)  # through it and past it
    v, omega = sim.object_velocity()
    # At the centre of mass, with no gravity or contact: dv = F d / m, no turn.
    np.testing.assert_allclose(v, force * 0.020 / cube.mass, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(omega, 0.0, atol=1e-9)
    sim.step(0.010)
    np.testing.assert_allclose(sim.object_velocity()[0], v, atol=1e-12)  # over: no force left


def test_a_push_on_a_link_moves_that_finger_only(allegro, cube):
    pushed, still = free_object(allegro, cube), free_object(allegro, cube)
    tip = allegro.link_names[int(np.flatnonzero(allegro.link_fingertip)[0])]
    pushed.schedule_push(np.array([0.0, 0.0, 2.0]), start=0.0, duration=0.010, link=tip)
    for sim in (pushed, still):
        sim.step(0.010)
    moved = np.abs(pushed.observe().q - still.observe().q)
    assert moved.max() > 1e-4
    np.testing.assert_allclose(pushed.object_velocity()[0], 0.0, atol=1e-12)
    assert not pushed.data.xfrc_applied.any()  # nothing left applied between steps
    pushed.clear_pushes()
    with pytest.raises(ConfigError, match="'no_link' is not a link of hand"):
        pushed.schedule_push(np.ones(3), 0.0, 0.01, link="no_link")
    with pytest.raises(ConfigError, match="duration > 0"):
        pushed.schedule_push(np.ones(3), 0.0, 0.0)


def test_the_protocol_names_its_phases_and_seeds_its_push():
    p = DisturbanceProtocol("impulse_20ms", seed=3, settle_time=0.2, recovery_time=0.3)
    assert [(ph.name, ph.duration) for ph in p.phases()] == [
        ("settle", 0.2),
        ("impulse_20ms", pytest.approx(0.32)),
    ]
    assert p.duration == pytest.approx(0.52)
    same = DisturbanceProtocol("pull", seed=3)
    np.testing.assert_array_equal(p.direction, same.direction)
    assert np.linalg.norm(p.direction) == pytest.approx(1.0)
    assert p.pick == same.pick and 0.0 <= p.pick < 1.0
    with pytest.raises(ConfigError, match="'shake' is unknown; use one of"):
        DisturbanceProtocol("shake")
    with pytest.raises(ConfigError, match="recovery_time must be > 0"):
        DisturbanceProtocol("pull", recovery_time=0.0)
    with pytest.raises(ConfigError, match="no cycle in phase 'settle'"):
        DisturbanceProtocol("pull", settle_time=0.01).check_rate(30.0)


def test_a_knock_pushes_a_touching_fingertip_away_from_the_object(allegro, cube):
    spec = TrialSpec(object=CUBE, grasp=0, disturbance="knock", seed=1, protocol_params=TINY)
    record = run_trial(spec, hand=allegro, obj=cube)
    event = record.meta["disturbance_event"]
    assert event["kind"] == "knock" and event["duration"] == DISTURBANCES["knock"].duration
    link = allegro.link_index(event["target"])
    assert allegro.link_fingertip[link]
    force = np.asarray(event["force"])
    assert np.linalg.norm(force) == pytest.approx(DISTURBANCES["knock"].magnitude)
    # Away from the object: along the link's contact normals, which point out of it.
    sim = registry.load(
        "backends",
        "mujoco",
        hand=allegro,
        obj=cube,
        q_init=load_grasps(allegro.name, CUBE)[0].q_array(allegro),
        wMo_init=load_grasps(allegro.name, CUBE)[0].object_pose(allegro.wMb),
    )
    contacts = sim.ground_truth_contacts()
    assert (contacts.n_world[contacts.link == link] @ force > 0.0).all()
    assert record.phases == ["settle", "knock"]
    assert outcome_of(record).phases_total == 2


class StillBackend(Backend):
    """A hand that does not move, on a simulation clock of 1 ms steps; keeps when each
    command was applied."""

    timestep = 1e-3

    def __init__(self, observation: Observation) -> None:
        self.observation, self.t, self.applied = observation, 0.0, []

    def observe(self):
        o = self.observation
        return Observation(o.q, o.dq, o.wMb, self.t, o.wMo, self.t, o.history)

    def apply(self, command):
        self.applied.append((round(self.t, 9), round(100 * float(command.tau[0]))))

    def step(self, duration):
        self.t += np.ceil(duration / self.timestep - 1e-9) * self.timestep

    @property
    def time(self):
        return self.t


class Computes(Stage):
    """Commands torque ``n / 100`` on joint 0 in cycle ``n``, after computing for the given seconds
    of a clock the test moves."""

    name = "computes"

    def __init__(self, clock, seconds):
        self.clock, self.seconds, self.n = clock, seconds, 0

    def step(self, context):
        self.clock.t += self.seconds[self.n]
        tau = np.zeros(context.hand.nv)
        tau[0] = self.n / 100
        self.n += 1
        return StageOutput(Command.torques(tau), "ok")


def test_compute_delay_applies_each_command_once_its_compute_time_has_passed(
    allegro, cube, monkeypatch
):
    clock = types.SimpleNamespace(t=0.0)
    monkeypatch.setattr(control_loop, "time", types.SimpleNamespace(perf_counter=lambda: clock.t))
    sim = grasp_sim(allegro, cube)
    backend = StillBackend(sim.observe())
    seconds = [0.0004, 0.0026, 0.0149, 0.0010, 0.0]
    loop = ControlLoop(
        backend, allegro, cube, Computes(clock, seconds), rate=100.0, compute_delay=True
    )
    report = loop.run(0.05)
    # 0.4 ms rounds to no step: at once; 2.6 ms to 3 steps; 14.9 ms outlasts the 10 ms period,
    # so the next cycle starts when it is applied, at 35 ms, and the schedule goes on at 40 ms.
    assert backend.applied == [(0.0, 0), (0.013, 1), (0.035, 2), (0.036, 3), (0.04, 4)]
    assert report.cycles == 5
    with pytest.raises(ConfigError, match="compute_delay .* needs a simulation clock"):
        wall = StillBackend(sim.observe())
        wall.clock = "wall"
        ControlLoop(wall, allegro, cube, Computes(clock, seconds), compute_delay=True)


def grasp_sim(allegro, cube):
    g = load_grasps(allegro.name, CUBE)[0]
    return registry.load(
        "backends",
        "mujoco",
        hand=allegro,
        obj=cube,
        q_init=g.q_array(allegro),
        wMo_init=g.object_pose(allegro.wMb),
    )


def test_the_study_pairs_every_variant_of_a_grasp_on_one_push():
    study = get_study("disturbance")
    jobs = study.jobs("quick", 0)
    cfg = CONFIGS["quick"]
    per_push = len(cfg.kinds) * len(cfg.tails) * len(cfg.rates)
    assert len(jobs) == len(cfg.objects) * len(cfg.grasps) * cfg.repeats * per_push
    by_grasp: dict[tuple[str, int], set[int]] = {}
    for job in jobs:
        by_grasp.setdefault((job.spec.object, job.spec.grasp), set()).add(job.spec.seed)
        tail = TAILS[job.labels["tail"]]
        assert job.spec.compute_delay == tail.get("compute_delay", False)
        assert job.spec.allocator_params == tail.get("allocator_params", {})
        assert job.spec.control_rate == job.labels["rate_hz"]
        assert job.spec.disturbance == job.labels["disturbance"]
    assert all(len(seeds) == 1 for seeds in by_grasp.values())
    assert len({s for seeds in by_grasp.values() for s in seeds}) == len(by_grasp)


def test_the_summary_finds_where_a_tail_falls_short():
    rows = []
    for grasp in range(4):
        for tail in ("none", "measured"):
            for rate in (30.0, 1000.0):
                # Only the measured tail at 30 Hz loses, on every grasp.
                lost = tail == "measured" and rate == 30.0
                rows.append(
                    {
                        "hand": "h",
                        "object": "o",
                        "grasp": grasp,
                        "disturbance": "pull",
                        "tail": tail,
                        "rate_hz": rate,
                        "held": not lost,
                        "held_strict": not lost,
                        "error": "",
                        "cycle_max_us": 900.0,
                    }
                )
    summary = get_study("disturbance").summarise(rows)
    cells = {(g["tail"], g["rate_hz"]): g for g in summary["groups"]}
    assert cells[("measured", 30.0)]["success"] == 0.0
    assert cells[("measured", 30.0)]["diff_to_ideal"] == -1.0
    assert cells[("measured", 30.0)]["falls_short"]
    assert not cells[("none", 30.0)]["falls_short"]
    enough = {e["tail"]: e["enough_hz"] for e in summary["enough_rate"]}
    assert enough == {"none": 30.0, "measured": 1000.0}
