"""Non-adaptive baselines (paper Sec. IV-A-1): feedforward torque and task-space impedance."""

from __future__ import annotations

import numpy as np
import pytest
from wholehand_plugins.feedforward import FeedforwardBaseline
from wholehand_plugins.impedance import STIFFNESS, ImpedanceBaseline
from wholehand_plugins.mujoco.backend import MujocoBackend

from wholehand import registry
from wholehand.allocation.base import Allocation, AllocationStatus, Allocator
from wholehand.allocation.baselines import FixedAllocationBaseline
from wholehand.backends import Backend, PushesObject
from wholehand.contacts.base import ContactSet
from wholehand.errors import ConfigError
from wholehand.grasps.store import load_grasps
from wholehand.models.kinematics import HandKinematics
from wholehand.trials.trial import TrialSpec, run_trial

OBJECT = "077_rubiks_cube"
TINY = {"settle_time": 0.1, "load_duration": 0.05, "rotation_time": 0.2}


class FixedForceAllocator(Allocator):
    """Returns given world forces on the contacts (a stand-in for the QP)."""

    def __init__(self, f_world: np.ndarray, status: AllocationStatus = AllocationStatus.OK) -> None:
        self.f_world, self.status = np.asarray(f_world, float), status

    def allocate(self, contacts, J_world, p_com_world, kinematics=None):  # noqa: ANN001, ANN201
        n = len(contacts)
        return Allocation(
            f_local=np.zeros((n, 3)),
            f_world=self.f_world.copy(),
            tau=np.zeros(J_world.shape[2]),
            residual_wrench=np.zeros(6),
            status=self.status,
        )


def _one_contact(hand, link_name: str, p_world: np.ndarray) -> ContactSet:
    return ContactSet(
        p_world=p_world[None].copy(),
        n_world=np.array([[0.0, 0.0, 1.0]]),
        link=np.array([hand.link_index(link_name)]),
        distance=np.zeros(1),
        link_actuated=np.asarray(hand.link_actuated),
        link_fingertip=np.asarray(hand.link_fingertip),
    )


def _q(hand, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return hand.neutral() + 0.3 * rng.uniform(0.0, 1.0, hand.nq)


@pytest.fixture
def tip_setup(allegro):
    """Kinematics at a bent configuration and a contact point on the index fingertip."""
    kin = HandKinematics(allegro)
    kin.update(_q(allegro, 0))
    link = "link_3.0_tip"
    p = kin.frame_pose(link)[:3, 3] + np.array([0.003, -0.002, 0.004])
    return kin, link, p


def _fd_point_jacobian(
    kin: HandKinematics, p_joint: np.ndarray, joint: int, q: np.ndarray
) -> np.ndarray:
    """(3, n_v) central finite differences of a body-fixed point's world position over q."""
    eps = 1e-6
    cols = []
    for k in range(q.size):
        dq = np.zeros_like(q)
        dq[k] = eps
        kin.update(q + dq)
        xp = kin.transform_points(p_joint[None], np.array([joint]))[0]
        kin.update(q - dq)
        xm = kin.transform_points(p_joint[None], np.array([joint]))[0]
        cols.append((xp - xm) / (2 * eps))
    kin.update(q)
    return np.stack(cols, axis=1)


def test_feedforward_one_contact_is_virtual_work(allegro, tip_setup):
    """tau = (dx/dq)^T f for one contact, the Jacobian taken by finite differences."""
    kin, link, p = tip_setup
    f = np.array([[0.4, -1.2, 2.5]])
    base = FeedforwardBaseline(actuated_dofs=allegro.actuated_dofs.copy())
    base.allocator = FixedForceAllocator(f)
    base.initialise(_one_contact(allegro, link, p), kin, np.zeros(3))
    joint = int(allegro.link_joint[allegro.link_index(link)])
    R, t = kin.joint_poses_in(np.eye(4))
    p_joint = R[joint].T @ (p - t[joint])
    J_fd = _fd_point_jacobian(kin, p_joint, joint, kin.q.copy())
    expected = J_fd.T @ f[0]
    expected[~allegro.actuated_dofs] = 0.0
    tau = base.command(kin)
    np.testing.assert_allclose(tau, expected, atol=1e-7)
    assert np.abs(tau).max() > 1e-3  # the contact does load some joints


def test_impedance_one_contact_is_spring_gradient(allegro, tip_setup):
    """At q0 the spring gives J^T f; elsewhere tau = -dU/dq with U = k/2 |x* - x(q)|^2."""
    kin, link, p = tip_setup
    f = np.array([[0.4, -1.2, 2.5]])
    base = ImpedanceBaseline(actuated_dofs=allegro.actuated_dofs.copy())
    base.allocator = FixedForceAllocator(f)
    base.initialise(_one_contact(allegro, link, p), kin, np.zeros(3))
    np.testing.assert_allclose(base.x_target[0], p + f[0] / STIFFNESS)
    J0 = kin.point_jacobians(base.joint, p[None])[0]
    np.testing.assert_allclose(base.command(kin), J0.T @ f[0], atol=1e-12)

    q1 = _q(allegro, 1)
    x_target, joint, p_joint = base.x_target[0], int(base.joint[0]), base.p_joint[0]

    def energy(q: np.ndarray) -> float:
        kin.update(q)
        x = kin.transform_points(p_joint[None], np.array([joint]))[0]
        return 0.5 * STIFFNESS * float(np.sum((x_target - x) ** 2))

    eps = 1e-6
    grad = np.array(
        [(energy(q1 + eps * e) - energy(q1 - eps * e)) / (2 * eps) for e in np.eye(q1.size)]
    )
    kin.update(q1)
    np.testing.assert_allclose(base.command(kin), -grad, atol=1e-6)
    assert not np.allclose(base.command(kin), J0.T @ f[0], atol=1e-4)


def test_impedance_at_initial_configuration_is_feedforward(allegro):
    """On real ground-truth contacts both baselines start with tau = J_gt^T f of the same QP."""
    from wholehand.models.object_catalogue import load_object

    obj = load_object(OBJECT)
    grasp = load_grasps("allegro_right", OBJECT)[0]
    backend = registry.load(
        "backends",
        "mujoco",
        hand=allegro,
        obj=obj,
        q_init=grasp.q_array(allegro),
        wMo_init=grasp.object_pose(allegro.wMb),
    )
    contacts = backend.ground_truth_contacts().to_contact_set(allegro)
    assert len(contacts) > 0
    state = backend.observe()
    p_com = state.wMo[:3, :3] @ obj.com + state.wMo[:3, 3]
    params = {"tau_max": allegro.tau_max.copy(), "actuated_dofs": allegro.actuated_dofs.copy()}
    taus = []
    for cls in (FeedforwardBaseline, ImpedanceBaseline):
        kin = HandKinematics(allegro)
        kin.update(state.q, state.wMb)
        base = cls(**params)
        initial = base.initialise(contacts, kin, p_com)
        assert initial.fresh
        J = base.J_gt
        expected = np.einsum("nak,na->k", J, initial.f_world)
        expected[~allegro.actuated_dofs] = 0.0
        np.testing.assert_allclose(base.command(kin), expected, atol=1e-9)
        np.testing.assert_allclose(base.command(kin), initial.tau, atol=1e-6)  # QP's own J^T f
        taus.append(base.command(kin))
    np.testing.assert_allclose(taus[0], taus[1], atol=1e-9)


def test_trial_feedforward_torque_never_changes_impedance_does(allegro):
    from wholehand.models.object_catalogue import load_object

    obj = load_object(OBJECT)
    taus = {}
    for cls in (FeedforwardBaseline, ImpedanceBaseline):
        spec = TrialSpec(
            object=OBJECT, grasp=0, theta_deg=60.0, allocator=cls, protocol_params=TINY
        )
        record = run_trial(spec, hand=allegro, obj=obj, stop_on_loss=False)
        a = record.arrays()
        assert (a["status"] == AllocationStatus.HOLD.value).all()
        assert record.meta["n_contacts_gt_init"] > 0
        taus[cls.__name__] = a["tau"]
    ff = taus["FeedforwardBaseline"]
    assert len(ff) > 100 and np.abs(ff).max() > 1e-3
    assert (ff == ff[0]).all()
    imp = taus["ImpedanceBaseline"]
    np.testing.assert_allclose(imp[0], ff[0], atol=1e-9)  # same start ...
    assert np.abs(imp - imp[0]).max() > 1e-4  # ... but it reacts to the hand's motion


def test_failed_initial_allocation_holds_zero(allegro, tip_setup):
    kin, link, p = tip_setup
    base = FeedforwardBaseline()
    base.allocator = FixedForceAllocator(np.ones((1, 3)), AllocationStatus.INFEASIBLE)
    initial = base.initialise(_one_contact(allegro, link, p), kin, np.zeros(3))
    assert initial.status is AllocationStatus.INFEASIBLE
    assert (base.command(kin) == 0.0).all()


def test_invalid_use_raises(allegro, tip_setup):
    kin, link, p = tip_setup
    contacts = _one_contact(allegro, link, p)
    J = kin.point_jacobians(allegro.link_joint[contacts.link], contacts.p_world)
    for cls in (FeedforwardBaseline, ImpedanceBaseline):
        base = cls()
        assert isinstance(base, FixedAllocationBaseline)
        with pytest.raises(ConfigError, match="initialise"):
            base.allocate(contacts, J, np.zeros(3), kin)
        base.initialise(contacts, kin, np.zeros(3))
        with pytest.raises(ConfigError, match="kinematics"):
            base.allocate(contacts, J, np.zeros(3))
    for bad in (0.0, -1.0, float("inf"), "300"):
        with pytest.raises(ConfigError, match="stiffness"):
            ImpedanceBaseline(stiffness=bad)
    with pytest.raises(ConfigError, match="mu"):
        FeedforwardBaseline(mu=-1.0)


class NoGroundTruthBackend(Backend, PushesObject):
    """MuJoCo behind the bare interface plus pushing: no ground truth, no reset."""

    def __init__(self, **params):  # noqa: ANN003
        self.sim = MujocoBackend(**params)

    def observe(self):  # noqa: ANN201
        return self.sim.observe()

    def apply(self, command):  # noqa: ANN001, ANN201
        self.sim.apply(command)

    def step(self, duration):  # noqa: ANN001, ANN201
        self.sim.step(duration)

    @property
    def time(self):  # noqa: ANN201
        return self.sim.time

    def apply_object_wrench(self, force_world, torque_world):  # noqa: ANN001, ANN201
        self.sim.apply_object_wrench(force_world, torque_world)

    def set_object_spring(self, *args):  # noqa: ANN002, ANN201
        self.sim.set_object_spring(*args)


def test_a_baseline_refuses_a_backend_without_ground_truth(allegro):
    """The need is declared (``needs_ground_truth``) and checked when the trial is set up; the
    adaptive controller runs over the same backend."""
    from wholehand.trials.trial import set_up_trial

    assert FeedforwardBaseline.needs_ground_truth and ImpedanceBaseline.needs_ground_truth
    spec = TrialSpec(
        object=OBJECT, theta_deg=0.0, backend=NoGroundTruthBackend, protocol_params=TINY
    )
    for method in ("feedforward", "impedance"):
        with pytest.raises(ConfigError, match="needs ground-truth contacts"):
            set_up_trial(TrialSpec(**{**spec.__dict__, "allocator": method}), allegro)
    record = run_trial(spec, hand=allegro)
    assert record.held_throughout and record.meta["n_contacts_gt_init"] is None
