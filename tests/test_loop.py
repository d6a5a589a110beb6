"""The closed loop in MuJoCo: realised versus desired forces, holding versus losing, determinism,
faults that never escape the loop, the backend's clock, and mixed joint groups."""

from __future__ import annotations

import dataclasses
from collections import Counter

import numpy as np
import pytest
from kernels_loaded import kernel_versions, loaded_since

from wholehand import registry
from wholehand.allocation.base import Allocation, AllocationStatus, Allocator
from wholehand.backends import Backend
from wholehand.backends.command import Command, JointTargets
from wholehand.backends.observation import Observation
from wholehand.contacts.base import ContactSet
from wholehand.errors import ConfigError
from wholehand.grasps.store import load_grasps
from wholehand.loop.control_loop import ControlLoop, Cycle, Observer
from wholehand.loop.record import RunRecord
from wholehand.loop.regulation import ForceRegulation
from wholehand.loop.stage import CycleContext, LoopStatus, Stage, StageOutput
from wholehand.models.object_catalogue import load_object
from wholehand.studies.rows import record_row
from wholehand.trials.outcome import outcome_of
from wholehand.trials.protocol import PerturbationProtocol
from wholehand.trials.trial import TrialSpec, run_trial

OBJECT = "077_rubiks_cube"
THREE_FINGER_GRASP = 4  # middle, ring and thumb (and the palm) touch the cube
SHORT = {"settle_time": 0.3, "load_duration": 0.4, "rotation_time": 0.4}
TINY = {"settle_time": 0.1, "load_duration": 0.05, "rotation_time": 0.2}


class ZeroTorqueAllocator(Allocator):
    """Commands no torque at all: the hand is limp."""

    def __init__(self, **params):
        pass

    def allocate(self, contacts, J_world, p_com_world, kinematics=None):
        n, n_v = len(contacts), J_world.shape[2]
        return Allocation(
            np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n_v), np.zeros(6), AllocationStatus.HOLD
        )


class ClaimsBalance(ZeroTorqueAllocator):
    """Says ``ok`` with no force at all."""

    def allocate(self, contacts, J_world, p_com_world, kinematics=None):
        return dataclasses.replace(
            super().allocate(contacts, J_world, p_com_world), status=AllocationStatus.OK
        )


class Last(Observer):
    """Keeps every cycle."""

    def __init__(self):
        self.cycles: list[Cycle] = []

    def on_cycle(self, cycle):
        self.cycles.append(cycle)


@pytest.fixture(scope="module")
def cube():
    return load_object(OBJECT)


def grasp_backend(hand, obj, grasp=THREE_FINGER_GRASP, backend=None):
    g = load_grasps(hand.name, obj.name)[grasp]
    cls = backend or "mujoco"
    return registry.load(
        "backends",
        cls,
        hand=hand,
        obj=obj,
        q_init=g.q_array(hand),
        wMo_init=g.object_pose(hand.wMb),
    )


def regulation(hand, obj, allocator="qp", **estimator_params):
    estimator = registry.load(
        "contact_estimators", "mesh_sdf", hand=hand, obj=obj, **estimator_params
    )
    alloc = registry.load("allocators", allocator, tau_max=hand.tau_max)
    return ForceRegulation(hand, obj, estimator, alloc)


def test_realised_forces_match_allocated_ones(allegro, cube):
    backend = grasp_backend(allegro, cube)
    seen = Last()
    ControlLoop(backend, allegro, cube, regulation(allegro, cube), observers=[seen]).run(1.0)
    cycle = seen.cycles[-1]
    assert len(seen.cycles) == 200 and cycle.output.status == "ok"
    allocation, contacts = cycle.output.allocation, cycle.output.contacts
    measured = backend.ground_truth_contacts()
    # Compare per rigid body (a link and its fixed fingertip are one body): the estimate has
    # several points per link, MuJoCo one or a few per touching geometry. Bodies the estimate
    # sees within d_thresh but that do not touch cannot realise their share; they are skipped.
    joint_est = allegro.link_joint[contacts.link]
    joint_gt = allegro.link_joint[measured.link]
    compared = 0
    for joint in np.unique(joint_gt):
        f_alloc = allocation.f_world[joint_est == joint].sum(axis=0)
        f_meas = measured.f_world[joint_gt == joint].sum(axis=0)
        a, m = np.linalg.norm(f_alloc), np.linalg.norm(f_meas)
        if m < 0.5:
            continue
        compared += 1
        assert f_alloc @ f_meas > np.cos(np.deg2rad(40.0)) * a * m, (joint, f_alloc, f_meas)
        assert 0.4 < m / a < 2.5, (joint, a, m)
    assert compared >= 4
    # In equilibrium the measured contact forces cancel on the free object.
    assert np.linalg.norm(measured.f_world.sum(axis=0)) < 0.05
    assert measured.f_normal.sum() > 5.0  # the hand squeezes


def test_qp_holds_the_load_test_and_a_limp_hand_loses_it(allegro, cube):
    # The paper's load test at full length: 0.5 s settling, then 0.1 m g for 1 s per direction.
    spec = TrialSpec(object=OBJECT, grasp=0, theta_deg=0.0)
    held = run_trial(spec, hand=allegro, obj=cube)
    assert held.held_throughout and len(held.arrays()["t"]) == 6.5 * 200
    assert outcome_of(held).held and outcome_of(held).failure_phase == ""
    limp = run_trial(
        TrialSpec(**{**spec.__dict__, "allocator": ZeroTorqueAllocator}), allegro, cube
    )
    outcome = outcome_of(limp)
    assert not limp.held_throughout and not outcome.held
    assert outcome.failure_phase in limp.phases and outcome.cycles < 6.5 * 200


def test_same_seed_same_record(allegro, cube, tmp_path):
    spec = TrialSpec(object=OBJECT, grasp=1, theta_deg=45.0, seed=3, protocol_params=SHORT)
    record = run_trial(spec, hand=allegro, obj=cube)
    loaded = RunRecord.load(record.save(tmp_path / "run.npz"))
    assert loaded.phases == record.phases and loaded.meta["spec"]["seed"] == 3
    assert loaded.phase_summary() == record.phase_summary()
    a, b = record.arrays(), loaded.arrays()
    for key in (*RunRecord.FIELDS, *RunRecord.CONTACT_FIELDS, "contact_offset"):
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert a["contact_offset"][-1] == a["n_contacts"].sum() == len(a["contact_link"])
    assert set(a["status"]) <= {s.value for s in AllocationStatus}  # stored by name
    assert set(a["stage"]) == {"regulate"}
    middle = len(a["t"]) // 2
    np.testing.assert_array_equal(
        loaded.contacts_at(middle)["contact_f"], record.contacts_at(middle)["contact_f"]
    )
    first = record.arrays()
    second = run_trial(spec, hand=allegro, obj=cube).arrays()
    for key in ("t", "phase", "n_contacts", "residual_wrench", "tau", "status", "held", "p_object"):
        np.testing.assert_array_equal(first[key], second[key], err_msg=key)
    other = run_trial(TrialSpec(**{**spec.__dict__, "seed": 4}), hand=allegro, obj=cube).arrays()
    assert not np.array_equal(first["p_object"][-1], other["p_object"][-1])


class KernelWatch(Observer):
    """The compiled kernel versions loaded between the loop's start (everything built) and its
    end."""

    def on_start(self, loop):
        self.before = kernel_versions()

    def on_end(self, loop):
        self.loaded = loaded_since(self.before)


def test_no_cycle_loads_a_kernel(allegro):
    """Constructors load every kernel version the cycles use, so no cycle pays milliseconds
    for one (edge screening included: the hardware controller's setting). The bottle's grasp 1
    pulled by 90 deg binds dozens of consistency rows."""
    bottle = load_object("006_mustard_bottle")
    for params in ({}, {"options": {"screen_edges": True}}):
        watch = KernelWatch()
        spec = TrialSpec(
            object=bottle.name,
            grasp=1,
            theta_deg=90.0,
            allocator_params=params,
            protocol_params=TINY,
        )
        run_trial(spec, hand=allegro, obj=bottle, observers=[watch])
        assert watch.loaded == {}, params


def test_an_old_record_is_refused_by_name(tmp_path):
    path = tmp_path / "old.npz"
    np.savez(path, stages=np.asarray(["settle"]), meta=np.asarray("{}"))
    with pytest.raises(ConfigError, match="record the run again"):
        RunRecord.load(path)


def test_protocol_phases_and_wrenches():
    protocol = PerturbationProtocol(theta_deg=60.0, seed=1)
    names = [s.name for s in protocol.phases()]
    assert names[:2] == ["settle", "load +x"] and "rotate" in names and names[-1] == "load2 -z"
    assert protocol.duration == pytest.approx(0.5 + 6 + protocol.rotation_time + 6)
    load = protocol.phases()[1]
    np.testing.assert_allclose(protocol.load_force(load, 2.0), [0.1 * 2.0 * 9.81, 0, 0])
    com = np.array([0.01, 0.0, 0.02])
    target, _, _ = protocol.spring(0.3, np.eye(3) * 1e-4, com, np.eye(4))
    angle = np.degrees(np.arccos((np.trace(target[:3, :3]) - 1) / 2))
    assert angle == pytest.approx(60.0)
    np.testing.assert_allclose(target[:3, :3] @ com + target[:3, 3], com, atol=1e-12)
    assert [s.name for s in PerturbationProtocol(theta_deg=0.0).phases()][-1] == "load -z"


def test_protocol_phases_follow_the_clock(allegro, cube):
    """Cycles per phase are duration x rate, whatever the float rounding of the clock."""
    spec = TrialSpec(object=OBJECT, grasp=0, theta_deg=30.0, protocol_params=TINY)
    a = run_trial(spec, hand=allegro, obj=cube, stop_on_loss=False).arrays()
    counts = np.bincount(a["phase"])
    protocol = PerturbationProtocol(theta_deg=30.0, **TINY)
    np.testing.assert_array_equal(counts, [round(p.duration * 200) for p in protocol.phases()])
    np.testing.assert_allclose(a["t"], np.arange(len(a["t"])) * 0.005, atol=1e-12)


@pytest.mark.parametrize("rate", [227.0, 66.0, 2000.0])
def test_a_rate_off_the_simulation_step_holds_on_average(allegro, cube, rate):
    """Cycle n starts at n / rate rounded up to the 1 ms step: 227 Hz is not 200 Hz (five steps
    a period), and a rate above the step's gives one cycle per step."""
    spec = TrialSpec(object=OBJECT, grasp=0, theta_deg=0.0, protocol_params=TINY, control_rate=rate)
    t = run_trial(spec, hand=allegro, obj=cube, stop_on_loss=False).arrays()["t"]
    steps = np.round(t / 1e-3)
    np.testing.assert_allclose(t, steps * 1e-3, atol=1e-9)  # on the simulation's steps
    if rate > 1000.0:
        np.testing.assert_array_equal(np.diff(steps), 1)
    else:
        np.testing.assert_array_equal(steps, np.ceil(np.arange(len(t)) * 1e3 / rate - 1e-6))


class FaultyBackend(Backend):
    """MuJoCo, with given cycles' observations corrupted or made impossible (cycle n of a 200 Hz
    loop, by its time: the loop may observe more than once a cycle, before its first)."""

    def __init__(self, sim, faults):
        self.sim, self.faults, self.t0 = sim, faults, sim.time

    def observe(self):
        obs = self.sim.observe()
        fault = self.faults.get(round((self.sim.time - self.t0) * 200.0))
        if fault is None:
            return obs
        q, wMb, wMo = obs.q.copy(), obs.wMb.copy(), obs.wMo.copy()
        if fault == "nan_pose":
            wMo[0, 3] = np.nan
        elif fault == "inf_q":
            q[3] = np.inf
        elif fault == "scaled_base":
            wMb = 2.0 * wMb
        elif fault == "short_q":
            q = q[:-1]
        elif fault == "far":  # well-formed but impossible, for the plausibility gate
            wMo[:3, 3] += [10.0, 0.0, 0.0]
        elif fault == "jump":
            wMo[:3, 3] += [0.05, 0.0, 0.0]  # 5 cm in 5 ms
        elif fault == "joint":  # no position a joint can have
            q[5] = 40.0
        elif fault == "off_limit":  # past the gate's margin, not a broken reading
            q[5] = 0.5 + float(self.sim.hand.q_upper[5])
        return Observation(q, obs.dq, wMb, obs.stamp_q, wMo, obs.stamp_object, obs.history)

    def apply(self, command):
        self.sim.apply(command)

    def step(self, duration):
        self.sim.step(duration)

    @property
    def time(self):
        return self.sim.time


def test_bad_observations_keep_the_last_torque(allegro, cube):
    faults = {20: "nan_pose", 21: "inf_q", 22: "scaled_base", 23: "short_q"}
    backend = FaultyBackend(grasp_backend(allegro, cube), faults)
    seen = Last()
    loop = ControlLoop(backend, allegro, cube, regulation(allegro, cube), observers=[seen])
    report = loop.run(0.2)
    statuses = [c.output.status for c in seen.cycles]
    assert statuses[19] == "ok" and statuses[24] == "ok"  # it recovers at once
    last_good = seen.cycles[19].command.tau
    assert np.abs(last_good).max() > 0.0
    for i in faults:
        assert statuses[i] == LoopStatus.BAD_STATE.value
        np.testing.assert_array_equal(seen.cycles[i].command.tau, last_good)
    assert "wMo" in seen.cycles[20].fault and "q contains NaN or inf" in seen.cycles[21].fault
    assert "wMb" in seen.cycles[22].fault
    assert "shape" in seen.cycles[23].fault
    assert report.faults == {"bad_state": 4} and report.n_errors == 0
    assert report.cycles == 40 and report.stopped_by == "duration"
    # The four faults in a row are one hold of the last torque, from cycle 20 (t = 0.1 s).
    assert report.held_commands == report.longest_hold == 4
    assert report.longest_hold_s == pytest.approx(4 * 0.005)
    assert report.longest_hold_at == pytest.approx(0.1)
    assert report.longest_hold_status == "bad_state"


class FailingEstimator:
    """Raises a plain ValueError on given calls (a broken plug-in, not a bad observation)."""

    def __init__(self, inner, fail_on):
        self.inner, self.fail_on, self.calls = inner, fail_on, 0

    def estimate(self, kinematics, wMo, stamp=0.0):
        self.calls += 1
        if self.calls in self.fail_on:
            raise ValueError("plug-in bug")
        return self.inner.estimate(kinematics, wMo, stamp)


def test_a_stage_exception_is_caught_recorded_and_reported(allegro, cube):
    stage = regulation(allegro, cube)
    stage.estimator = FailingEstimator(stage.estimator, {11, 12})
    seen = Last()
    report = ControlLoop(grasp_backend(allegro, cube), allegro, cube, stage, observers=[seen]).run(
        0.1
    )
    statuses = [c.output.status for c in seen.cycles]
    assert statuses[10] == statuses[11] == LoopStatus.STAGE_ERROR.value
    assert statuses[9] == statuses[12] == "ok"
    np.testing.assert_array_equal(seen.cycles[11].command.tau, seen.cycles[9].command.tau)
    assert report.n_errors == 2 and report.faults == {"stage_error": 2}
    assert (
        report.held_commands == report.longest_hold == 2
        and report.longest_hold_status == "stage_error"
    )
    assert "ValueError: plug-in bug" in report.errors[0].error
    assert "FailingEstimator" not in report.errors[0].error  # the message, the trace below
    assert "in estimate" in report.errors[0].traceback


def test_a_trial_whose_stage_raises_is_an_error_row(allegro, cube, monkeypatch):
    from wholehand_plugins.mesh_sdf import MeshSDFEstimator

    estimate = MeshSDFEstimator.estimate
    calls = []

    def flaky(self, kinematics, wMo, stamp=0.0):
        calls.append(1)
        if len(calls) == 5:
            raise RuntimeError("boom")
        return estimate(self, kinematics, wMo, stamp)

    monkeypatch.setattr(MeshSDFEstimator, "estimate", flaky)
    record = run_trial(TrialSpec(object=OBJECT, theta_deg=0.0, protocol_params=TINY), allegro)
    assert record.meta["loop"]["n_errors"] == 1
    assert "RuntimeError: boom" in outcome_of(record).error
    row = record_row(record)
    assert row["failure_stage"] == "error" and "boom" in row["error"]


class FakeWallClock:
    """A wall clock the test moves: time passes only when the backend waits or a stage
    computes, so a run on it is the same every time, whatever the machine's load."""

    def __init__(self) -> None:
        self.t = 0.0


class WallClockBackend(Backend):
    """A hand that does not move, on a wall clock: time passes while the stage computes."""

    clock = "wall"

    def __init__(self, sim, clock: FakeWallClock):
        self.sim, self.clock_ = sim, clock
        self.observation = sim.observe()

    def observe(self):
        o = self.observation
        t = self.time
        o.history.push(t, o.q, o.wMb)
        return Observation(o.q, o.dq, o.wMb, t, o.wMo, t, o.history)

    def apply(self, command):
        pass

    def step(self, duration):
        self.clock_.t += duration

    @property
    def time(self):
        return self.clock_.t


class SlowStage(Stage):
    """Zero torque; every third cycle computes for three control periods (``slow=False``:
    none does)."""

    name = "slow"

    def __init__(self, dt, clock: FakeWallClock, slow: bool = True):
        self.dt, self.n, self.clock, self.slow = dt, 0, clock, slow

    def step(self, context):
        self.n += 1
        if self.slow and self.n % 3 == 0:
            self.clock.t += 3 * self.dt
        return StageOutput(Command.torques(np.zeros(context.hand.nv)), "ok")


def test_a_wall_clock_overrun_is_measured_not_absorbed(allegro, cube):
    rate = 50.0
    clock = FakeWallClock()
    backend = WallClockBackend(grasp_backend(allegro, cube), clock)
    stage = SlowStage(1.0 / rate, clock)
    seen = Last()
    report = ControlLoop(backend, allegro, cube, stage, rate=rate, observers=[seen]).run(0.6)
    # Every third cycle takes 3 periods: it overruns its period by 2 of them, and the next
    # cycle starts when it ends (the schedule restarts rather than cycles crowding in).
    ts = np.array([c.t for c in seen.cycles])
    np.testing.assert_allclose(np.diff(ts)[:6], [0.02, 0.02, 0.06, 0.02, 0.02, 0.06])
    slow = stage.n // 3
    assert slow >= 2 and report.overruns == slow
    assert report.max_overrun == pytest.approx(2.0 / rate)
    assert report.cycles == 18  # 3 cycles per 0.1 s: fewer than 0.6 s x 50 Hz


class WaitingBackend(WallClockBackend):
    """A wall-clock backend that waits for a fresh joint state after each sleep: 1 ms before
    every even cycle, none before odd ones, summed in ``sync_wait`` as the ROS 2 backend's."""

    def __init__(self, sim, clock: FakeWallClock):
        super().__init__(sim, clock)
        self.sync_wait, self.steps = 0.0, 0

    def step(self, duration):
        self.steps += 1
        wait = 0.001 if self.steps % 2 == 0 else 0.0
        self.clock_.t += duration + wait
        self.sync_wait += wait


def test_late_cycles_keep_what_each_overrun_cycle_was_doing(allegro, cube):
    """The slow cycles (three periods each, a garbage collection in each) are the late ones:
    one record per overrun, with the stage, the time to the next cycle on the loop's clock and
    the joint-state wait before the cycle."""
    import gc

    from wholehand.robot.late_cycles import LateCycles

    rate = 50.0
    clock = FakeWallClock()
    backend = WaitingBackend(grasp_backend(allegro, cube), clock)

    class CollectingStage(SlowStage):
        def step(self, context):
            if self.n % 3 == 2:  # the next step is a slow one
                gc.collect()
            return super().step(context)

    late, seen = LateCycles(), Last()
    stage = CollectingStage(1.0 / rate, clock)
    report = ControlLoop(backend, allegro, cube, stage, rate=rate, observers=[seen, late]).run(0.6)
    assert report.overruns >= 2 and late.count == report.overruns == len(late.kept)
    slow = [c for c in seen.cycles if (c.index + 1) % 3 == 0]
    assert [r.t for r in late.kept] == [c.t for c in slow[: late.count]]

    def wait_before(index: int) -> float:
        return 0.001 if index % 2 == 0 and index > 0 else 0.0

    for record, cycle in zip(late.kept, slow, strict=False):
        assert record.stage == "slow" and record.status == "ok" and record.period_s == 0.02
        assert record.to_next_s == pytest.approx(3.0 / rate + wait_before(cycle.index + 1))
        assert record.joint_wait_s == pytest.approx(wait_before(cycle.index))
        assert record.collections >= 1 and record.cycle_s == cycle.cycle_time
        assert record.solve_s == record.solver_s == 0.0 and record.contacts == 0  # no allocation
    assert late._collected not in gc.callbacks  # removed at the end of the run


def test_a_slow_preload_before_the_first_cycle_is_not_a_late_cycle(allegro, cube):
    """A process's first loads (the stages' preload, the observers' start) may take longer than
    a period on a wall clock; the schedule starts after them, so the cycles are on time."""
    rate = 50.0
    clock = FakeWallClock()
    backend = WallClockBackend(grasp_backend(allegro, cube), clock)

    class SlowPreload(SlowStage):
        def preload(self, context):
            clock.t += 3.0 / rate  # three periods of first loads

    seen = Last()
    stage = SlowPreload(1.0 / rate, clock, slow=False)
    report = ControlLoop(backend, allegro, cube, stage, rate=rate, observers=[seen]).run(0.2)
    assert report.overruns == 0 and report.cycles == 10
    np.testing.assert_allclose(seen.cycles[0].t, 3.0 / rate)


def _thumb_dofs(hand):
    links = [i for i, f in enumerate(hand.link_finger) if f == hand.config.thumb]
    joints = sorted({int(hand.link_joint[i]) for i in links} - {0})
    return np.array([hand.model.joints[j].idx_v for j in joints])


class ThumbHeldRegulation(Stage):
    """Force regulation on the fingers, the thumb held at its grasp angles by joint targets."""

    name = "mixed"

    def __init__(self, inner, thumb, q_thumb):
        self.inner, self.thumb, self.q_thumb = inner, thumb, q_thumb

    def start(self, context):
        self.inner.start(context)

    def step(self, context):
        out = self.inner.step(context)
        if out.command is None:
            return out
        tau = out.command.tau.copy()
        tau[self.thumb] = 0.0
        hold = JointTargets(self.thumb, self.q_thumb, None, 1.0, 0.02, name="thumb")
        return StageOutput(Command(tau, (hold,)), out.status, out.contacts, out.allocation)


def test_position_and_torque_groups_share_the_loop(allegro, cube):
    grasp = load_grasps(allegro.name, OBJECT)[0]
    backend = grasp_backend(allegro, cube, grasp=0)
    thumb = _thumb_dofs(allegro)
    assert len(thumb) == 4
    q_thumb = grasp.q_array(allegro)[thumb]
    # The paper's contact selection: the 0.05 rad tracking bound below was set on it.
    stage = ThumbHeldRegulation(regulation(allegro, cube, hysteresis=0.0), thumb, q_thumb)
    seen = Last()
    ControlLoop(backend, allegro, cube, stage, observers=[seen]).run(0.5)
    cycle = seen.cycles[-1]
    assert cycle.output.status == "ok" and cycle.command.targets[0].name == "thumb"
    # The thumb tracks its targets; the torque joints get exactly their torques.
    obs = backend.observe()
    assert np.abs(obs.q[thumb] - q_thumb).max() < 0.05
    applied = backend.applied_torques()
    others = np.setdiff1d(np.arange(allegro.nv), thumb)
    expected = np.clip(cycle.command.tau[others], -allegro.tau_max[others], allegro.tau_max[others])
    np.testing.assert_allclose(applied[others], expected, atol=1e-12)
    # The thumb's torque is its PD law at the state of the last MuJoCo step.
    d, s = backend.data, backend.scene
    q_prev = d.qpos[s.qpos_index][thumb] - d.qvel[s.qvel_index][thumb] * backend.timestep
    assert np.abs(applied[thumb]).max() > 0.0
    pd = 1.0 * (q_thumb - q_prev) - 0.02 * d.qvel[s.qvel_index][thumb]
    limit = allegro.tau_max[thumb]
    np.testing.assert_allclose(applied[thumb], np.clip(pd, -limit, limit), atol=5e-3)
    assert (cycle.command.tau[thumb] == 0.0).all()


def test_command_and_targets_reject_bad_groups(allegro):
    with pytest.raises(ConfigError, match="overlap"):
        Command(
            np.zeros(4),
            (JointTargets([0, 1], [0, 0], None, 1, 0), JointTargets([1], [0], None, 1, 0)),
        )
    with pytest.raises(ConfigError, match="outside"):
        Command(np.zeros(4), (JointTargets([4], [0.0], None, 1, 0),))
    with pytest.raises(ConfigError, match=">= 0"):
        JointTargets([0], [0.0], None, -1.0, 0.0)
    with pytest.raises(ConfigError, match="give q, dq"):
        JointTargets([0], None, None, 1.0, 0.0)


def test_stage_transitions_and_the_end(allegro, cube):
    class Count(Stage):
        def __init__(self, name, n, nxt):
            self.name, self.n, self.nxt, self.started = name, n, nxt, 0

        def start(self, context):
            self.started += 1

        def step(self, context: CycleContext):
            self.n -= 1
            return StageOutput(
                Command.torques(np.zeros(context.hand.nv)),
                self.name,
                next=self.nxt if self.n == 0 else None,
            )

    a, b = Count("a", 3, "b"), Count("b", 2, "end")
    seen = Last()
    report = ControlLoop(
        grasp_backend(allegro, cube), allegro, cube, {"a": a, "b": b}, observers=[seen]
    ).run()
    assert [c.stage for c in seen.cycles] == ["a", "a", "a", "b", "b"]
    assert report.stopped_by == "end" and a.started == b.started == 1
    with pytest.raises(ConfigError, match="not one of"):
        ControlLoop(grasp_backend(allegro, cube), allegro, cube, {"a": a}, first="c")


class MinimalAllocator(Allocator):
    """A third-party allocator written as docs/plugins.md says, with no constructor keywords."""

    def __init__(self):
        self.calls = 0

    def allocate(self, contacts, J_world, p_com_world, kinematics=None):
        assert kinematics is not None and kinematics.q.shape == (J_world.shape[2],)
        n = len(contacts)
        return Allocation(
            np.zeros((n, 3)),
            np.zeros((n, 3)),
            np.zeros(J_world.shape[2]),
            np.zeros(6),
            AllocationStatus.OK,
        )


def test_an_allocator_gets_only_the_hand_keywords_it_accepts(allegro):
    from wholehand.trials.trial import load_allocator

    assert isinstance(load_allocator(MinimalAllocator, allegro, {}), MinimalAllocator)
    qp = load_allocator("qp", allegro, {"mu": 0.5})
    np.testing.assert_array_equal(qp.params.tau_max, allegro.tau_max)
    record = run_trial(
        TrialSpec(object=OBJECT, theta_deg=0.0, allocator=MinimalAllocator, protocol_params=TINY),
        allegro,
        stop_on_loss=False,
    )
    assert record.meta["loop"]["n_errors"] == 0 and (record.arrays()["tau"] == 0).all()


def test_a_bad_observation_is_recorded_as_unknown_and_a_bad_switch_is_reported(allegro, cube):
    from wholehand.loop.grasp_loss import GraspLossMonitor
    from wholehand.loop.record import Recorder

    backend = FaultyBackend(grasp_backend(allegro, cube), {3: "short_q", 4: "nan_pose"})
    loss = GraspLossMonitor(allegro, cube)
    recorder = Recorder(loss)
    ControlLoop(backend, allegro, cube, regulation(allegro, cube), observers=[loss, recorder]).run(
        0.05
    )
    a = recorder.record.arrays()
    assert a["q"].shape == (10, allegro.nq) and np.isnan(a["q"][3]).all()
    assert np.isnan(a["p_object"][4]).any() and np.isfinite(a["q"][4]).all()
    assert list(a["status"][3:5]) == ["bad_state", "bad_state"] and a["held"].all()

    class Wrong(Stage):
        name = "wrong"

        def step(self, context):
            return StageOutput(Command.torques(np.zeros(context.hand.nv)), "ok", next="nowhere")

    report = ControlLoop(grasp_backend(allegro, cube), allegro, cube, Wrong()).run(0.02)
    assert report.cycles == 4 and report.n_errors == 4 and "'nowhere'" in report.errors[0].error


def test_no_pose_yet_keeps_the_last_command_and_a_pose_free_stage_runs(allegro, cube):
    from wholehand.grasps.closing import ClosingStage
    from wholehand.loop.filters import PoseDropout

    seen = Last()
    blind = [PoseDropout([(0.0, 0.02)])]
    report = ControlLoop(
        grasp_backend(allegro, cube),
        allegro,
        cube,
        regulation(allegro, cube),
        filters=blind,
        observers=[seen],
    ).run(0.05)
    statuses = [c.output.status for c in seen.cycles]
    assert statuses[:4] == ["no_pose"] * 4 and statuses[4] == "ok"
    assert report.faults == {"no_pose": 4}
    assert not any(c.command.tau.any() for c in seen.cycles[:4])
    q = np.zeros(allegro.nq)
    closing = ClosingStage(q, np.zeros(allegro.nv), np.zeros(allegro.nv, dtype=bool))
    seen = Last()
    ControlLoop(
        grasp_backend(allegro, cube), allegro, cube, closing, filters=blind, observers=[seen]
    ).run(0.02)
    assert [c.output.status for c in seen.cycles] == ["closing"] * 4


class Silent(Stage):
    """Commands zero torques except on the given cycles, where it gives none."""

    name = "silent"
    needs_object_pose = False

    def __init__(self, nv, quiet):
        self.nv, self.quiet, self.calls = nv, quiet, 0

    def step(self, context):
        self.calls += 1
        if self.calls - 1 in self.quiet:
            return StageOutput(None, "quiet")
        return StageOutput(Command.torques(np.zeros(self.nv)), "ok")


def test_the_longest_hold_of_the_last_command_is_reported_and_warned_once(allegro, cube, caplog):
    """Cycles without a new command are held runs: the longest one is reported with when it
    began and why, and a hold reaching HOLD_WARNING_S (20 cycles at 200 Hz) is logged once."""
    quiet = set(range(5, 8)) | set(range(10, 40)) | set(range(45, 47))
    stage = Silent(allegro.nv, quiet)
    with caplog.at_level("WARNING", logger="wholehand.loop.control_loop"):
        report = ControlLoop(grasp_backend(allegro, cube), allegro, cube, stage).run(0.25)
    assert report.cycles == 50 and report.held_commands == len(quiet) == 35
    assert report.longest_hold == 30 and report.longest_hold_s == pytest.approx(30 * 0.005)
    assert report.longest_hold_at == pytest.approx(10 * 0.005)
    assert report.longest_hold_status == "quiet"
    warnings = [r.getMessage() for r in caplog.records if "held for" in r.getMessage()]
    assert len(warnings) == 1 and "held for 0.100 s since t = 0.0500 s (quiet first)" in warnings[0]
    assert report.as_dict()["longest_hold"] == 30


def test_the_gate_refuses_a_glitch_and_accepts_a_sustained_change(allegro, cube):
    from wholehand.loop.gate import GateLimits, ObservationGate

    faults = {10: "far", 11: "jump", 12: "off_limit", **{i: "off_limit" for i in range(20, 26)}}
    gate = ObservationGate(allegro, GateLimits(accept_after=4))
    seen = Last()
    backend = FaultyBackend(grasp_backend(allegro, cube), faults)
    ControlLoop(backend, allegro, cube, regulation(allegro, cube), observers=[seen], gate=gate).run(
        0.15
    )
    statuses = [c.output.status for c in seen.cycles]
    for i in (10, 11, 12):
        assert statuses[i] == "bad_state", i
        np.testing.assert_array_equal(seen.cycles[i].command.tau, seen.cycles[9].command.tau)
    assert "beyond 1.0 m" in seen.cycles[10].fault and "m/s" in seen.cycles[11].fault
    assert "joint 'joint_" in seen.cycles[12].fault and "by more than 0.2" in seen.cycles[12].fault
    assert statuses[13] == "ok"  # the glitches are over
    # Six cycles of a joint 0.5 rad past its limit: three refused, then accepted while it lasts.
    assert statuses[20:23] == ["bad_state"] * 3 and statuses[23:26] == ["ok"] * 3
    assert gate.accepted == {"joints": 1} and gate.refused["joints"] == 4
    with pytest.raises(ConfigError, match="accept_after"):
        GateLimits(accept_after=0)


def test_the_gates_measures_against_pinocchio_and_numpy():
    import pinocchio as pin

    from wholehand.loop.gate import _measures

    rng = np.random.default_rng(5)
    lower, upper = -np.ones(4), np.ones(4)
    for angle in (0.0, 1e-9, 1e-3, 0.5, 2.0, np.pi - 1e-6, np.pi):
        axis = rng.normal(size=3)
        ref, now, base = np.eye(4), np.eye(4), np.eye(4)
        ref[:3, :3] = pin.exp3(rng.normal(size=3))
        now[:3, :3] = ref[:3, :3] @ pin.exp3(angle * axis / np.linalg.norm(axis))
        ref[:3, 3], now[:3, 3], base[:3, 3] = rng.normal(size=(3, 3))
        q = np.array([0.0, 1.5, -2.0, 0.5])
        first, distance, moved, turned = _measures(q, lower, upper, now, base, ref)
        assert first == 1
        assert distance == pytest.approx(np.linalg.norm(now[:3, 3] - base[:3, 3]), rel=1e-14)
        assert moved == pytest.approx(np.linalg.norm(now[:3, 3] - ref[:3, 3]), rel=1e-14)
        assert turned == pytest.approx(angle, abs=1e-7)
    assert _measures(np.zeros(4), lower, upper, None, base, None)[0] == -1
    assert np.isnan(_measures(np.zeros(4), lower, upper, now, base, None)[2])


class Shouting(Stage):
    """Commands ten times the limit on every joint, or a torque of the wrong length, or one
    with an infinite or NaN entry."""

    name = "shouting"

    def __init__(self, wrong_length_on=(), not_finite_on=()):
        self.n, self.wrong, self.not_finite = 0, set(wrong_length_on), dict(not_finite_on)

    def step(self, context):
        self.n += 1
        nv = context.hand.nv
        tau = np.full(nv - 1 if self.n in self.wrong else nv, 10.0)
        if self.n in self.not_finite:
            tau[-1] = self.not_finite[self.n]
        return StageOutput(Command.torques(tau), "ok")


def test_every_command_is_clamped_and_a_malformed_one_is_a_stage_error(allegro, cube):
    backend = grasp_backend(allegro, cube)
    seen = Last()
    loop = ControlLoop(
        backend, allegro, cube, Shouting({3}, {5: np.inf, 6: np.nan}), observers=[seen]
    )
    report = loop.run(0.04)
    limit = np.where(allegro.actuated_dofs, allegro.tau_max, 0.0)
    for c in seen.cycles:
        assert np.all(np.abs(c.command.tau) <= limit)
    np.testing.assert_array_equal(seen.cycles[0].command.tau, limit)
    assert np.all(np.abs(backend.applied_torques()) <= limit + 1e-12)
    assert report.clamped == 5 and report.max_excess == pytest.approx(10.0 - limit.min())
    assert seen.cycles[2].output.status == "stage_error" and "shape (15,)" in seen.cycles[2].fault
    np.testing.assert_array_equal(seen.cycles[2].command.tau, seen.cycles[1].command.tau)
    for i in (4, 5):  # inf, then NaN: refused, the last command kept
        assert seen.cycles[i].output.status == "stage_error"
        assert "with NaN or inf" in seen.cycles[i].fault
        np.testing.assert_array_equal(seen.cycles[i].command.tau, seen.cycles[3].command.tau)


def test_an_allocation_that_does_not_balance_has_its_own_status(allegro, cube):
    from wholehand.allocation.base import is_balanced

    f = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    assert is_balanced(np.zeros(6), f) and not is_balanced(np.zeros(6), np.zeros((2, 3)))
    assert not is_balanced([2e-3, 0, 0, 0, 0, 0], f) and not is_balanced([0, 0, 0, 0, 2e-4, 0], f)
    held = run_trial(TrialSpec(object=OBJECT, theta_deg=0.0, protocol_params=TINY), allegro)
    assert outcome_of(held).unbalanced_cycles == 0
    # A squeeze the joints cannot make: the QP's best is within the limits but leaves a residual.
    spec = TrialSpec(
        object=OBJECT, theta_deg=0.0, protocol_params=TINY, allocator_params={"f_n_min": 1e6}
    )
    record = run_trial(spec, allegro, stop_on_loss=False)
    outcome, a = outcome_of(record), record.arrays()
    unbalanced = a["status"] == "unbalanced"
    assert unbalanced.any() and not (a["status"] == "ok").any()
    assert outcome.unbalanced_cycles == unbalanced.sum()
    residual = np.linalg.norm(a["residual_wrench"][unbalanced, :3], axis=1)
    assert residual.min() > 1.0  # newtons: far from balance, and said so
    # Another allocator's "ok" is still checked: zero forces hold nothing.
    spec = TrialSpec(object=OBJECT, theta_deg=0.0, protocol_params=TINY, allocator=ClaimsBalance)
    limp = run_trial(spec, allegro, stop_on_loss=False)
    claimed = int((limp.arrays()["status"] == "ok").sum())
    assert claimed and outcome_of(limp).unbalanced_cycles == claimed
    assert np.all(np.abs(a["tau"]) <= allegro.tau_max)  # and never beyond the limits


class FlatNormals:
    """The paper's estimator, with every third contact's normal zeroed or NaN (as an SDF gives
    inside a thin object)."""

    def __init__(self, inner):
        self.inner, self.seen = inner, []

    def estimate(self, kinematics, wMo, stamp=0.0):
        c = self.inner.estimate(kinematics, wMo, stamp)
        n = c.n_world.copy()
        n[::3] = 0.0
        n[1::6] = np.nan
        return ContactSet(
            c.p_world, n, c.link, c.distance, c.link_actuated, c.link_fingertip, c.stamp
        )


class SpyAllocator(Allocator):
    def __init__(self, inner):
        self.inner, self.normals = inner, []

    def allocate(self, contacts, J_world, p_com_world, kinematics=None):
        self.normals.append(contacts.n_world.copy())
        return self.inner.allocate(contacts, J_world, p_com_world, kinematics)


def test_degenerate_normals_never_reach_the_allocator(allegro, cube):
    stage = regulation(allegro, cube)
    stage.estimator = FlatNormals(stage.estimator)
    stage.allocator = spy = SpyAllocator(stage.allocator)
    seen = Last()
    ControlLoop(grasp_backend(allegro, cube), allegro, cube, stage, observers=[seen]).run(0.1)
    assert stage.degenerate_normals > 0 and spy.normals
    for n in spy.normals:
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    assert {c.output.status for c in seen.cycles} == {"ok"}


def test_allocating_once_per_pose_holds_the_torque_between_poses(allegro, cube):
    from wholehand.loop.filters import PoseTracker
    from wholehand.loop.regulation import POSE_HELD

    backend = grasp_backend(allegro, cube)
    stage = regulation(allegro, cube)
    stage.allocate_every = "pose"
    seen = Last()
    loop = ControlLoop(
        backend,
        allegro,
        cube,
        stage,
        rate=200.0,
        filters=[PoseTracker(30.0, 0.033)],
        observers=[seen],
    )
    loop.run(0.2)
    stamps = [c.context.obs.stamp_object for c in seen.cycles]
    statuses = [c.output.status for c in seen.cycles]
    for i in range(1, len(stamps)):  # a new pose allocates, a repeated one holds
        assert (statuses[i] == POSE_HELD) == (stamps[i] == stamps[i - 1])
        if statuses[i] == POSE_HELD:
            np.testing.assert_array_equal(
                seen.cycles[i].command.tau, seen.cycles[i - 1].command.tau
            )
    assert 5 <= statuses.count("ok") <= 8  # 30 Hz poses in 0.2 s
    with pytest.raises(ConfigError, match="allocate_every='sometimes'"):
        ForceRegulation(allegro, cube, stage.estimator, stage.allocator, allocate_every="sometimes")


class OvershootingClock(WallClockBackend):
    """A virtual wall clock whose every sleep lasts 0.3 ms longer than asked, as OS sleeps do;
    one sleep (the fifth) lasts 2.5 periods longer."""

    def __init__(self, sim, dt, clock):
        super().__init__(sim, clock)
        self.dt, self.steps = dt, 0

    def step(self, duration):
        self.steps += 1
        self.clock_.t += duration + 3e-4 + (2.5 * self.dt if self.steps == 5 else 0.0)


def test_wall_clock_cycles_keep_their_schedule_despite_sleep_overshoot(allegro, cube):
    dt = 0.01
    clock = FakeWallClock()
    backend = OvershootingClock(grasp_backend(allegro, cube), dt, clock)
    seen = Last()
    stage = SlowStage(dt, clock, slow=False)  # only the clock's overshoot
    report = ControlLoop(backend, allegro, cube, stage, rate=1 / dt, observers=[seen]).run(0.2)
    ts = np.array([c.t for c in seen.cycles])
    # Cycles 1-4 start 0.3 ms after k * dt (no drift); the 2.5-period sleep is one overrun,
    # after which the schedule restarts from that cycle: again 0.3 ms after each dt.
    np.testing.assert_allclose(ts[1:5], dt * np.arange(1, 5) + 3e-4, atol=1e-12)
    assert report.overruns == 1
    np.testing.assert_allclose(np.diff(ts[6:]), dt, atol=1e-12)
    assert len(ts) == 17  # 0.2 s less the 2.5 periods lost, at 10 ms


def test_replaying_a_record_reproduces_the_loops_torques(allegro, cube):
    from wholehand.bench.worst_case import replay

    spec = TrialSpec(object=OBJECT, grasp=THREE_FINGER_GRASP, theta_deg=0.0, protocol_params=TINY)
    record = run_trial(spec, allegro, cube)
    out, statuses = replay(record, allegro, cube, regulation(allegro, cube))
    recorded = record.arrays()
    assert statuses == Counter(recorded["status"].tolist())
    ok = recorded["status"] == "ok"
    np.testing.assert_allclose(out["tau"][ok], recorded["tau"][ok], atol=1e-6)
    assert (out["step"] >= out["qp"]).all() and (out["qp"][ok] > 0).all()
    # The solver's own time is part of the allocation's, and never all of it.
    assert (out["qp_solver"][ok] > 0).all() and (out["qp_solver"] < out["qp"])[ok].all()


def test_a_supported_settle_holds_the_object_until_the_loads(allegro):
    """With gravity on, the mustard bottle (0.6 kg) falls out of the Allegro's grasp during a
    free settle; on the settle's support (sagging 1 mm under the weight) it stays within a few
    millimetres until the support goes at the first load."""
    from wholehand.models.object_catalogue import load_object

    bottle = load_object("006_mustard_bottle")
    drift = {}
    for supported in (True, False):
        params = {**TINY, "settle_time": 0.3, "supported_settle": supported}
        spec = TrialSpec(
            object=bottle.name, grasp=0, theta_deg=0.0, gravity=True, protocol_params=params
        )
        a = run_trial(spec, hand=allegro, obj=bottle, stop_on_loss=False).arrays()
        settle = a["phase"] == 0
        drift[supported] = np.linalg.norm(a["p_object"][settle] - a["p_object"][0], axis=1).max()
    assert drift[True] < 0.005
    assert drift[False] > 0.1  # free fall over most of the 0.3 s (0.44 m)
    protocol = PerturbationProtocol(supported_settle=True)
    _, (k_lin, _), _ = protocol.spring(0.6, np.eye(3) * 1e-4, np.zeros(3), np.eye(4), rotate=False)
    assert 0.6 * 9.81 / k_lin == pytest.approx(1e-3)  # the support's sag


@pytest.mark.parametrize(
    ("flags", "longest"),
    [([], 0), ([0, 0], 0), ([1, 1, 1], 3), ([0, 1, 1, 0, 1], 2), ([1, 0, 1, 1, 1, 0, 1, 1], 3)],
)
def test_the_longest_run_of_cycles_without_a_torque(flags, longest):
    from wholehand.bench.worst_case import longest_run

    assert longest_run(np.array(flags, dtype=bool)) == longest


def test_percentiles_count_the_samples_over_a_1khz_period():
    from wholehand.timing import percentiles_us

    ns = np.concatenate([np.full(997, 200_000), [1_000_000, 1_000_001, 5_000_000]])
    stats = percentiles_us(ns)  # 1000 samples: 997 at 200 us, one at exactly 1 ms, two over
    assert (stats["p50_us"], stats["p99_us"], stats["max_us"]) == (200.0, 200.0, 5000.0)
    assert stats["p99.9_us"] == pytest.approx(np.percentile(ns / 1e3, 99.9), abs=0.01)
    assert (stats["n"], stats["n_over_1ms"]) == (1000, 2)


def test_cycle_benchmark_pools_every_cycle_until_each_trials_loss():
    from wholehand.bench.cycle import run_cycle_benchmark

    objects = (OBJECT, "006_mustard_bottle")
    out = run_cycle_benchmark(
        objects=objects, ks=(1,), grasps=(0,), theta_deg=90.0, protocol_params=TINY
    )
    (row,) = out["results"]
    assert out["objects"] == list(objects) and out["theta_deg"] == 90.0 and row["trials"] == 2
    lengths = []
    for name in objects:  # the same trials, each until its loss
        spec = TrialSpec(
            object=name, theta_deg=90.0, estimator_params={"k": 1}, protocol_params=TINY
        )
        lengths.append(len(run_trial(spec, stop_on_loss=True).arrays()["t"]))
    full = round(PerturbationProtocol(theta_deg=90.0, **TINY).duration * 200)
    assert all(n <= full for n in lengths)
    assert row["cycle"]["n"] == row["qp"]["n"] == row["estimate"]["n"] == sum(lengths)
    assert row["grasps_held"] == sum(n == full for n in lengths)
    assert row["cycle"]["n_over_1ms"] <= row["cycle"]["n"] and out["machine"]["commit"]
    # No allocation ever meets a nanosecond's deadline: every cycle holds the first command.
    (late,) = run_cycle_benchmark(
        objects=(OBJECT,),
        ks=(1,),
        grasps=(0,),
        protocol_params=TINY,
        allocator_params={"options": {"deadline": 1e-9}},
    )["results"]
    assert late["held_commands"] == late["longest_hold_cycles"] == late["cycle"]["n"] > 0


def test_recorded_contact_benchmark_times_each_phase_of_the_loops_states():
    from wholehand.bench.estimate import PHASES, run_recorded_contact_benchmark

    out = run_recorded_contact_benchmark(
        obj=OBJECT, grasp=0, theta_deg=0.0, protocol_params=TINY, repeats=2
    )
    protocol = PerturbationProtocol(theta_deg=0.0, **TINY)
    assert out["held"] and out["states"] == round(protocol.duration * 200)
    assert set(out["phases"]) == set(PHASES)
    assert all(out["phases"][p]["n"] == 2 * out["states"] for p in PHASES)
    assert out["kept_contacts_mean"] > 0
    # The total is the phases' sum cycle by cycle, so its mean is the sum of their means.
    means = sum(out["phases"][p]["mean_us"] for p in PHASES)
    assert out["total"]["mean_us"] == pytest.approx(means, abs=0.02)


def test_a_joint_reading_far_past_its_limit_is_refused_without_the_gate(allegro, cube):
    """A joint 40 rad past its limit is no position: bad_state and the last torque, gate or not;
    a reading a little past it (a pressed finger in MuJoCo) is used."""
    from wholehand.loop.control_loop import BROKEN_READING

    backend = FaultyBackend(grasp_backend(allegro, cube), {i: "joint" for i in range(10, 13)})
    seen = Last()
    loop = ControlLoop(backend, allegro, cube, regulation(allegro, cube), observers=[seen])
    report = loop.run(0.1)
    statuses = [c.output.status for c in seen.cycles]
    assert statuses[10:13] == ["bad_state"] * 3 and statuses[13] == "ok"
    assert "reads 40, more than 1.0 past its limits" in seen.cycles[10].fault
    np.testing.assert_array_equal(seen.cycles[12].command.tau, seen.cycles[9].command.tau)
    assert report.faults == {"bad_state": 3}
    q = allegro.neutral()
    q[5] = allegro.q_upper[5] + 0.9 * BROKEN_READING
    loop._check_joint_range(q)  # past the limit, but a position the joint can be pushed to


def test_a_pose_out_of_reach_holds_the_last_torque_then_ramps_it_to_zero(allegro, cube):
    """A tracker glitch 10 m away while regulating: tracking_lost, the last torque held for
    TRACKING_HOLD, then ramped linearly to zero over TRACKING_RAMP; back in reach, regulation
    resumes."""
    from wholehand.loop.tracking import TRACKING_HOLD, TRACKING_RAMP

    glitch = range(20, 20 + 180)  # 0.9 s at 200 Hz
    backend = FaultyBackend(grasp_backend(allegro, cube), dict.fromkeys(glitch, "far"))
    seen = Last()
    stage = regulation(allegro, cube)
    assert 0.3 < stage.reach.radius < 1.0
    loop = ControlLoop(backend, allegro, cube, stage, observers=[seen])
    loop.run(1.1)
    statuses = [c.output.status for c in seen.cycles]
    assert statuses[19] == "ok" and set(statuses[20:200]) == {"tracking_lost"}
    assert statuses[200] == "ok"
    last = seen.cycles[19].command.tau
    hold = round(TRACKING_HOLD * 200)
    for k in range(180):
        held = k * 0.005
        scale = np.clip(1.0 - (held - TRACKING_HOLD) / TRACKING_RAMP, 0.0, 1.0)
        np.testing.assert_allclose(seen.cycles[20 + k].command.tau, scale * last, atol=1e-12)
    assert np.abs(seen.cycles[20 + hold + round(TRACKING_RAMP * 200)].command.tau).max() == 0.0
