"""The hand's own weight: actuator gravity torques that hold the fingers still in MuJoCo, and the
allocator's torque bias (the limits bind ``bias + J^T f``) against hand-derived forces and the
reference QP."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import qpsolvers
from test_allocation import CASES, antipodal, objective, settings_for
from toy_hand import write_toy_hand
from wholehand_plugins.fingertip_only import FingertipOnlyAllocator
from wholehand_plugins.mujoco.backend import MujocoBackend
from wholehand_plugins.qp import QPAllocator

from wholehand import registry
from wholehand.allocation.base import AllocationStatus
from wholehand.allocation.options import SolveOptions
from wholehand.allocation.problem import AllocationParams, build_allocation_qp
from wholehand.allocation.reference import direct_problem, solved_problem
from wholehand.backends.command import Command
from wholehand.bench.synthetic_grasps import synthetic_grasp
from wholehand.errors import ConfigError
from wholehand.loop.regulation import ForceRegulation
from wholehand.models.gravity import GravityCompensation
from wholehand.models.hand import HandModel, load_hand
from wholehand.models.objects import ObjectModel


@pytest.fixture(scope="module")
def coupled_toy(tmp_path_factory) -> HandModel:
    return load_hand(write_toy_hand(tmp_path_factory.mktemp("hands") / "toy", mimic=True))


def _drift(hand: HandModel, compensate: bool) -> float:
    """Largest joint motion [rad] in 1 s of a hand whose base is turned on its side, with no
    contact, its actuators commanding the gravity torques (or nothing) every 5 ms."""
    wMb = np.eye(4)
    wMb[:3, :3] = pin.exp3(np.array([1.0, 1.0, 0.0]))  # tilted: gravity across every joint axis
    far = np.eye(4)
    far[:3, 3] = [2.0, 2.0, 2.0]
    q0 = hand.neutral()
    backend = MujocoBackend(
        hand, ObjectModel.sphere(0.01, mass=0.01), far, q0, gravity=True, wMb=wMb
    )
    comp = GravityCompensation(hand)
    for _ in range(200):
        obs = backend.observe()
        tau = comp.actuation_torques(obs.q, obs.wMb) if compensate else np.zeros(hand.n_actuation)
        backend.apply(Command.torques(hand.joint_torques(tau)))
        backend.step(0.005)
    return float(np.abs(backend.observe().q - q0).max())


@pytest.mark.parametrize("which", ["allegro", "coupled_toy"])
def test_actuation_gravity_torques_hold_the_fingers_still(request, which: str) -> None:
    # The coupled toy's followers have no motor: C^T g puts their links' weight on the leader.
    hand = request.getfixturevalue(which)
    assert _drift(hand, compensate=True) < 2e-3
    assert _drift(hand, compensate=False) > 0.02


def test_actuation_gravity_torques_are_c_transpose_g(coupled_toy: HandModel) -> None:
    comp = GravityCompensation(coupled_toy)
    q, wMb = coupled_toy.neutral(), np.eye(4)
    g = comp.torques(q, wMb)
    np.testing.assert_allclose(comp.actuation_torques(q, wMb), coupled_toy.coupling.T @ g)


def test_the_limits_bind_bias_plus_contact_torques() -> None:
    # Antipodal fingertips (lever 1 cm) need 5 N each for a balanced 10 N squeeze: 0.05 N*m per
    # joint. With a 0.06 N*m limit and joint 0 already carrying -0.02 N*m, joint 0 may add only
    # -0.04 N*m: 4 N. The best then is 4 N against 6 N (sum 10 N), 2 N of net force along x.
    cs, J, com = antipodal()
    bias = np.array([-0.02, 0.0])
    alloc = QPAllocator(
        consistency=False,
        tau_max=0.06,
        options=SolveOptions(solver="daqp", solver_settings=settings_for("daqp")),
    )
    free = alloc.allocate(cs, J, com)
    np.testing.assert_allclose(free.f_local[:, 0], [5.0, 5.0], rtol=1e-4)
    out = alloc.allocate(cs, J, com, tau_bias=bias)
    assert out.status is AllocationStatus.UNBALANCED  # 2 N left over, below
    np.testing.assert_allclose(out.f_local[:, 0], [4.0, 6.0], rtol=1e-4)
    np.testing.assert_allclose(out.tau, [-0.04, -0.06], rtol=1e-4)  # the contact part alone
    np.testing.assert_allclose(np.abs(out.residual_wrench[0]), 2.0, rtol=1e-4)
    # The fingertip-only ablation passes the bias on.
    tips = FingertipOnlyAllocator(
        consistency=False, tau_max=0.06, options=SolveOptions(solver="daqp")
    )
    np.testing.assert_allclose(tips.allocate(cs, J, com, tau_bias=bias).tau, out.tau, rtol=1e-4)


@pytest.mark.parametrize("case", CASES)
def test_a_biased_allocation_is_the_reference_optimum(case: tuple[int, int, float]) -> None:
    n, seed, tmax = case
    cs, J, com = synthetic_grasp(seed, n).cycle()
    # On every joint, a bias in the direction the unbiased allocation turns it, leaving room
    # for only 90 % of that torque: the unbiased allocation would now exceed every limit.
    unbiased = QPAllocator(tau_max=tmax, options=SolveOptions(solver="daqp")).allocate(cs, J, com)
    bias = np.sign(unbiased.tau) * (tmax - 0.9 * np.abs(unbiased.tau))
    moved = np.abs(unbiased.tau) > 1e-6
    assert (np.abs(bias + unbiased.tau)[moved] > tmax).all()
    alloc = QPAllocator(
        tau_max=tmax, options=SolveOptions(solver="daqp", solver_settings=settings_for("daqp"))
    )
    out = alloc.allocate(cs, J, com, tau_bias=bias)
    assert out.fresh
    assert (np.abs(bias + out.tau) <= tmax + 1e-6).all()
    qp = build_allocation_qp(cs, J, com, alloc.params, tau_bias=bias)
    ref = qpsolvers.solve_problem(solved_problem(qp), solver="daqp", primal_tol=1e-10)
    assert ref.found and ref.primal_residual() < 1e-9 and ref.dual_residual() < 1e-9
    lam = alloc.last_solution.x[: qp.n_lambda]
    best = objective(qp, ref.x[: qp.n_lambda])
    assert objective(qp, lam) == pytest.approx(best, rel=1e-5, abs=1e-8)
    # The paper's form on local forces agrees on the torques it allows.
    direct = qpsolvers.solve_problem(direct_problem(qp), solver="daqp", primal_tol=1e-10)
    assert direct.found
    tau_direct = qp.J_act.T @ (qp.wRc[qp.act_idx] @ direct.x.reshape(-1, 3, 1)[qp.act_idx]).ravel()
    assert (np.abs(bias + tau_direct) <= tmax + 1e-6).all()


def test_bad_biases_are_named_or_refused_without_raising() -> None:
    cs, J, com = antipodal()
    alloc = QPAllocator(consistency=False, options=SolveOptions(solver="daqp"))
    with pytest.raises(ConfigError, match="tau_bias must be 2 finite joint torques"):
        alloc.allocate(cs, J, com, tau_bias=np.zeros(3))
    nan = alloc.allocate(cs, J, com, tau_bias=np.array([np.nan, 0.0]))
    assert nan.status is AllocationStatus.SOLVER_FAILED and nan.tau is None
    with pytest.raises(ConfigError, match="tau_bias"):
        build_allocation_qp(cs, J, com, AllocationParams(), tau_bias=np.zeros(1))


def test_gravity_compensation_needs_an_allocator_that_takes_a_bias(allegro) -> None:
    cube = ObjectModel.box((0.05, 0.05, 0.05))
    feedforward = registry.load("allocators", "feedforward")
    with pytest.raises(ConfigError, match="supports_tau_bias is False"):
        ForceRegulation(allegro, cube, None, feedforward, gravity_compensation=True)  # type: ignore[arg-type]
