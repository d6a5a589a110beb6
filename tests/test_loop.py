"""The closed loop in MuJoCo: realised versus desired forces, holding versus losing, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from wholehand import registry
from wholehand.allocation.base import Allocation, AllocationStatus, Allocator
from wholehand.backends.base import HandObjectState
from wholehand.grasps.store import load_grasps
from wholehand.loop.controller import ForceRegulationController
from wholehand.loop.protocol import PerturbationProtocol
from wholehand.loop.record import RunRecord
from wholehand.loop.trial import TrialSpec, run_trial
from wholehand.models.objects import load_object

OBJECT = "077_rubiks_cube"
THREE_FINGER_GRASP = 4  # middle, ring and thumb (and the palm) touch the cube
SHORT = {"settle_time": 0.3, "load_duration": 0.4, "rotation_time": 0.4}


class ZeroTorqueAllocator(Allocator):
    """Commands no torque at all: the hand is limp."""

    def __init__(self, **params):
        pass

    def allocate(self, contacts, J_world, p_com_world):
        n, n_v = len(contacts), J_world.shape[2]
        return Allocation(
            np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n_v), np.zeros(6), AllocationStatus.HOLD
        )


@pytest.fixture(scope="module")
def cube():
    return load_object(OBJECT)


def settled(allegro, cube, allocator, seconds=1.0):
    grasp = load_grasps(allegro.name, OBJECT)[THREE_FINGER_GRASP]
    backend = registry.load(
        "backends", "mujoco", hand=allegro, obj=cube,
        q_init=grasp.q_array(allegro), wMo_init=grasp.object_pose(allegro.wMb),
    )  # fmt: skip
    estimator = registry.load("contact_estimators", "mesh_sdf", hand=allegro, obj=cube)
    alloc = registry.load("allocators", allocator, tau_max=allegro.tau_max)
    controller = ForceRegulationController(allegro, cube, estimator, alloc)
    for _ in range(int(seconds * 200)):
        cycle = controller.step(backend.read_state())
        backend.apply_torques(cycle.allocation.tau)
        backend.step(0.005)
    cycle = controller.step(backend.read_state())
    backend.apply_torques(cycle.allocation.tau)
    return backend, cycle


def test_realised_forces_match_allocated_ones(allegro, cube):
    backend, cycle = settled(allegro, cube, "qp")
    assert cycle.allocation.ok
    measured = backend.ground_truth_contacts()
    # Compare per rigid body (a link and its fixed fingertip are one body): the estimate has
    # several points per link, MuJoCo one or a few per touching geometry. Bodies the estimate
    # sees within d_thresh but that do not touch cannot realise their share; they are skipped.
    joint_est = allegro.link_joint[cycle.contacts.link]
    joint_gt = allegro.link_joint[measured.link]
    compared = 0
    for joint in np.unique(joint_gt):
        f_alloc = cycle.allocation.f_world[joint_est == joint].sum(axis=0)
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
    limp = run_trial(
        TrialSpec(**{**spec.__dict__, "allocator": ZeroTorqueAllocator}), allegro, cube
    )
    assert not limp.held_throughout


def test_same_seed_same_record(allegro, cube, tmp_path):
    spec = TrialSpec(object=OBJECT, grasp=1, theta_deg=45.0, seed=3, protocol_params=SHORT)
    record = run_trial(spec, hand=allegro, obj=cube)
    loaded = RunRecord.load(record.save(tmp_path / "run.npz"))
    assert loaded.stages == record.stages and loaded.meta["spec"]["seed"] == 3
    assert loaded.stage_summary() == record.stage_summary()
    a, b = record.arrays(), loaded.arrays()
    for key in (*RunRecord.FIELDS, *RunRecord.CONTACT_FIELDS, "contact_offset"):
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert a["contact_offset"][-1] == a["n_contacts"].sum() == len(a["contact_link"])
    middle = len(a["t"]) // 2
    np.testing.assert_array_equal(
        loaded.contacts_at(middle)["contact_f"], record.contacts_at(middle)["contact_f"]
    )
    first = record.arrays()
    second = run_trial(spec, hand=allegro, obj=cube).arrays()
    for key in ("t", "stage", "n_contacts", "residual_wrench", "tau", "status", "held", "p_object"):
        np.testing.assert_array_equal(first[key], second[key], err_msg=key)
    other = run_trial(TrialSpec(**{**spec.__dict__, "seed": 4}), hand=allegro, obj=cube).arrays()
    assert not np.array_equal(first["p_object"][-1], other["p_object"][-1])


def test_protocol_stages_and_wrenches():
    protocol = PerturbationProtocol(theta_deg=60.0, seed=1)
    names = [s.name for s in protocol.stages()]
    assert names[:2] == ["settle", "load +x"] and "rotate" in names and names[-1] == "load2 -z"
    assert protocol.duration == pytest.approx(0.5 + 6 + protocol.rotation_time + 6)
    load = protocol.stages()[1]
    np.testing.assert_allclose(protocol.load_force(load, 2.0), [0.1 * 2.0 * 9.81, 0, 0])
    com = np.array([0.01, 0.0, 0.02])
    target, _, _ = protocol.spring(0.3, np.eye(3) * 1e-4, com, np.eye(4))
    angle = np.degrees(np.arccos((np.trace(target[:3, :3]) - 1) / 2))
    assert angle == pytest.approx(60.0)
    np.testing.assert_allclose(target[:3, :3] @ com + target[:3, 3], com, atol=1e-12)
    assert [s.name for s in PerturbationProtocol(theta_deg=0.0).stages()][-1] == "load -z"


def test_bad_observations_keep_the_last_torque(allegro, cube):
    backend, cycle = settled(allegro, cube, "qp", seconds=0.2)
    controller_torque = cycle.allocation.tau
    assert cycle.allocation.ok and np.abs(controller_torque).max() > 0.0
    estimator = registry.load("contact_estimators", "mesh_sdf", hand=allegro, obj=cube)
    alloc = registry.load("allocators", "qp", tau_max=allegro.tau_max)
    controller = ForceRegulationController(allegro, cube, estimator, alloc)
    good = backend.read_state()
    first = controller.step(good)
    assert first.allocation.ok
    bad_pose = good.wMo.copy()
    bad_pose[0, 3] = np.nan
    bad_q = good.q.copy()
    bad_q[3] = np.inf
    for bad in (
        HandObjectState(good.q, good.dq, good.wMb, bad_pose, good.stamp_q, good.stamp_object),
        HandObjectState(bad_q, good.dq, good.wMb, good.wMo, good.stamp_q, good.stamp_object),
        HandObjectState(good.q, good.dq, 2.0 * good.wMb, good.wMo, good.stamp_q, good.stamp_object),
    ):
        result = controller.step(bad)
        assert result.allocation.status is AllocationStatus.BAD_STATE
        np.testing.assert_array_equal(result.allocation.tau, first.allocation.tau)
        assert len(result.contacts) == 0
    assert controller.bad_states == 3 and "wMb" in controller.last_fault
    assert controller.step(good).allocation.ok  # and it recovers


def test_backend_params_reach_the_backend():
    """``TrialSpec.backend_params`` configure the MuJoCo scene: without self-collision no hand
    geom collides with another hand geom; an unknown option is named."""
    from wholehand.backends.mujoco_scene import HAND_BIT
    from wholehand.errors import ConfigError
    from wholehand.loop.trial import set_up_trial

    spec = TrialSpec(theta_deg=0.0)
    with_self = set_up_trial(spec).backend
    without = set_up_trial(
        TrialSpec(theta_deg=0.0, backend_params={"self_collision": False})
    ).backend
    hand_geoms = with_self.model.geom_contype == HAND_BIT
    assert np.all(with_self.model.geom_conaffinity[hand_geoms] & HAND_BIT)
    assert not np.any(
        without.model.geom_conaffinity[without.model.geom_contype == HAND_BIT] & HAND_BIT
    )
    with pytest.raises(ConfigError, match="unknown options \\['colour'\\]"):
        set_up_trial(TrialSpec(theta_deg=0.0, backend_params={"colour": 1}))
