"""The dual active-set solver built for the allocation QP, against the KKT conditions written
out here and against DAQP on the same problems: synthetic grasps, a recorded cycle before a loss,
external wrenches and link weights, a rank-deficient actuation Jacobian, warm starts right and
wrong, infeasible problems and the iteration limit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_allocation import (
    CASES,
    _case_problems,
    antipodal,
    check_allocation,
    contact_set,
    near_loss,
    objective,
)
from wholehand_plugins.qp import QPAllocator

import wholehand.allocation.solvers.dual_active_set as das_module
from wholehand.allocation.base import AllocationStatus
from wholehand.allocation.options import SolveOptions
from wholehand.allocation.problem import AllocationParams, AllocationQP, build_allocation_qp
from wholehand.allocation.solve import solve_allocation
from wholehand.allocation.solvers import make_solver
from wholehand.allocation.solvers.dual_active_set import (
    allocation_rows,
    infeasibility_certificate,
    solve_dual_active_set,
)
from wholehand.allocation.solvers.dual_active_set_kernel import (
    DIVERGED,
    NUMERICAL,
    dual_active_set,
)
from wholehand.bench.synthetic_grasps import synthetic_grasp
from wholehand.contacts.base import ContactSet


def _problems() -> list[tuple[str, AllocationQP]]:
    out = _case_problems()  # the synthetic grasps and the recorded near-loss cycle
    cs, J, com = near_loss()
    params = AllocationParams.checked("test")
    rng = np.random.default_rng(4)
    weight = np.array([0.0, 0.0, -2.5, 0.01, -0.02, 0.0])  # a weight off the COM
    bias = rng.uniform(-0.05, 0.05, J.shape[2])
    out.append(
        ("near loss, weight and bias", build_allocation_qp(cs, J, com, params, "t", weight, bias))
    )
    cs, J, com = synthetic_grasp(1, 12).cycle()
    used = np.flatnonzero(np.abs(J[cs.actuated]).sum(axis=(0, 1)) > 0)
    J[:, :, used[1]] = J[:, :, used[0]]  # two equal joint columns: J_act loses rank
    out.append(("rank deficient", build_allocation_qp(cs, J, com, params)))
    return out


PROBLEMS = _problems()


def dense_rows(qp: AllocationQP) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every row, the consistency ones formed: (m, 4N), lo, hi."""
    t_lo, t_hi = qp.torque_bounds()
    eps = qp.params.eps_margin
    A = np.vstack([np.ones((1, qp.n_lambda)), qp.T_lam, qp.null_rows(np.arange(qp.n_null))])
    lo = np.r_[qp.params.f_n_min, t_lo, np.full(qp.n_null, -eps)]
    hi = np.r_[np.inf, t_hi, np.full(qp.n_null, eps)]
    return A, lo, hi


def assert_kkt(qp: AllocationQP, lam: np.ndarray, y: np.ndarray, tol: float = 1e-7) -> None:
    """Stationarity, primal and dual feasibility and complementarity, each written out."""
    A, lo, hi = dense_rows(qp)
    G = qp.G_lam
    gradient = G.T @ (G @ lam + qp.w_ext) + qp.params.reg * lam
    z = gradient - A.T @ y  # the bounds' multipliers stationarity leaves
    scale = max(1.0, float(np.abs(gradient).max()))
    assert (lam >= -tol).all()
    values = A @ lam
    assert (values >= lo - tol).all() and (values <= hi + tol).all()
    assert (z >= -tol * scale).all()
    assert np.abs(z[lam > tol]).max(initial=0.0) <= tol * scale
    at_lo = np.abs(values - lo) <= tol * np.maximum(1.0, np.abs(lo))
    at_hi = np.abs(values - hi) <= tol * np.maximum(1.0, np.abs(hi))
    assert (y[y > 0] >= 0).all() and at_lo[y > tol * scale].all()
    assert at_hi[y < -tol * scale].all()


@pytest.mark.parametrize(("name", "qp"), PROBLEMS, ids=[p[0] for p in PROBLEMS])
def test_cold_solves_meet_the_kkt_conditions_and_daqps_optimum(name, qp):
    sol, y, _ = solve_dual_active_set(qp)
    assert sol.status == "optimal", sol.detail
    lam = sol.x[: qp.n_lambda]
    assert_kkt(qp, lam, y)
    reference = solve_allocation(qp, make_solver("daqp", {"primal_tol": 1e-10}), screening=False)
    best = objective(qp, reference.x[: qp.n_lambda]) if not qp.w_ext.any() else None
    if best is not None:
        assert objective(qp, lam) == pytest.approx(best, rel=1e-7, abs=1e-10)
    np.testing.assert_allclose(qp.tau(lam), qp.tau(reference.x[: qp.n_lambda]), atol=1e-6)
    np.testing.assert_allclose(sol.x[qp.n_lambda :], qp.G_lam @ lam + qp.w_ext)
    np.testing.assert_allclose(sol.torque_values, qp.T_lam @ lam, atol=1e-12)
    np.testing.assert_allclose(sol.null_values, qp.null_values(lam), atol=1e-9)
    assert sol.relative_violation < 1e-7


@pytest.mark.parametrize(("name", "qp"), PROBLEMS, ids=[p[0] for p in PROBLEMS])
def test_a_warm_start_at_the_optimum_takes_no_step_and_a_wrong_one_still_ends_there(name, qp):
    cold, y, _ = solve_dual_active_set(qp)
    lam = cold.x[: qp.n_lambda]
    warm, _, _ = solve_dual_active_set(qp, lam > 0.0, np.sign(y).astype(np.int8))
    assert warm.status == "optimal" and warm.iterations == 0
    np.testing.assert_allclose(warm.x, cold.x, rtol=0, atol=1e-6)
    rng = np.random.default_rng(len(name))
    wrong_rows = rng.integers(-1, 2, y.size).astype(np.int8)
    wrong_free = rng.random(qp.n_lambda) < 0.5
    wrong, y_wrong, _ = solve_dual_active_set(qp, wrong_free, wrong_rows)
    assert wrong.status == "optimal"
    assert_kkt(qp, wrong.x[: qp.n_lambda], y_wrong)
    np.testing.assert_allclose(qp.tau(wrong.x[: qp.n_lambda]), qp.tau(lam), atol=1e-6)


def test_implicit_consistency_rows_equal_formed_ones():
    """The rows held through the Householder QR give the same steps and solution as the same
    rows formed densely."""
    qp = dict(PROBLEMS)["near loss"]
    A, qr, lo, hi = allocation_rows(qp)
    assert qr[0].size and A.shape[0] == 1 + qp.torque_rows.size  # the implicit path
    dense, _, _ = dense_rows(qp)
    n, m = qp.n_lambda, lo.size
    args = (np.ascontiguousarray(qp.G_lam), qp.w_ext, qp.params.reg)
    start = (np.zeros(n, bool), np.zeros(m, np.int8), 1e-9, 5000)
    norms = np.sqrt((dense * dense).sum(axis=1))  # both choose by the rows' true norms
    implicit = dual_active_set(*args, A, *qr, qp.W, qp.act_idx, lo, hi, norms.copy(), *start)
    empty = (np.zeros((0, 0), order="F"), np.zeros(0))
    formed = dual_active_set(*args, dense, *empty, qp.W, qp.act_idx, lo, hi, norms, *start)
    assert implicit[3] == formed[3] == 0 and implicit[4] == formed[4]
    np.testing.assert_allclose(implicit[5], dense @ implicit[0], atol=1e-9)  # the rows' values
    np.testing.assert_allclose(implicit[0], formed[0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(implicit[1], formed[1], atol=1e-6)


def test_the_rank_deficient_basis_takes_formed_rows():
    qp = dict(PROBLEMS)["rank deficient"]
    assert qp.null is not None and qp.null.householder() is None
    A, qr, lo, hi = allocation_rows(qp)
    assert qr[0].size == 0 and A.shape[0] == lo.size


def test_infeasible_problems_are_named_and_the_allocator_gives_no_torque():
    cs, J, com = antipodal(lever=1.0)  # 10 N of squeeze needs 10 N*m > 0.2 N*m
    qp = build_allocation_qp(cs, J, com, AllocationParams.checked("test"))
    sol, _, _ = solve_dual_active_set(qp)
    assert sol.status == "infeasible" and sol.x is None
    out = QPAllocator(options=SolveOptions(solver="dual_active_set")).allocate(cs, J, com)
    assert out.status is AllocationStatus.INFEASIBLE and out.tau is None


def test_the_iteration_limit_fails_and_the_allocator_falls_back_to_daqp(monkeypatch):
    qp = dict(PROBLEMS)["near loss"]
    sol, _, _ = solve_dual_active_set(qp, max_steps=5)
    assert sol.status == "failed" and sol.x is None and sol.detail == "iteration limit"
    import wholehand.allocation.solvers.dual_active_set as das

    monkeypatch.setattr(
        "wholehand.allocation.cycle_solver.solve_dual_active_set",
        lambda qp, free, rows, scale, max_steps: das.solve_dual_active_set(
            qp, free, rows, max_steps=5
        ),
    )
    cs, J, com = near_loss()
    alloc = QPAllocator(options=SolveOptions(solver="dual_active_set"))
    out = alloc.allocate(cs, J, com)
    assert out.tau is not None
    assert "dual active set" not in alloc.last_solution.detail  # DAQP's answer
    check_allocation(out, cs, J, com, alloc.params)


@pytest.mark.parametrize("case", CASES)
def test_a_control_sequence_with_warm_starts_stays_optimal(case):
    """Cycles of a moving grasp, each warm-started from the last: every allocation passes the
    independent constraint checks and matches DAQP's torques."""
    n, seed, tmax = case
    grasp = synthetic_grasp(seed, n)
    das = QPAllocator(tau_max=tmax, options=SolveOptions(solver="dual_active_set"))
    daqp = QPAllocator(tau_max=tmax)
    steps = []
    for _ in range(12):
        cs, J, com = grasp.cycle()
        out, ref = das.allocate(cs, J, com), daqp.allocate(cs, J, com)
        check_allocation(out, cs, J, com, das.params)
        np.testing.assert_allclose(out.tau, ref.tau, atol=1e-6)
        steps.append(das.last_solution.iterations)
    assert np.median(steps[1:]) < steps[0] or steps[0] == 0


def test_the_consistency_rows_norms_are_learnt_where_formed():
    qp = dict(PROBLEMS)["near loss"]
    sol, y, scale = solve_dual_active_set(qp)
    dense, _, _ = dense_rows(qp)
    true = np.sqrt((dense * dense).sum(axis=1))[1 + qp.torque_rows.size :]
    mu2 = qp.params.mu**2
    learnt = scale != np.sqrt(2 * mu2 + (4 - 2 * mu2) / 3)  # the average a row starts with
    assert learnt.sum() >= np.count_nonzero(y[1 + qp.torque_rows.size :])
    np.testing.assert_allclose(scale[learnt], true[learnt], rtol=1e-12)
    again = solve_dual_active_set(qp, null_scale=scale)
    assert again.solution.status == "optimal"


def test_an_exception_in_the_solver_falls_back_to_daqp(monkeypatch):
    def boom(*args, **kwargs):
        raise RuntimeError("kernel crashed")

    monkeypatch.setattr("wholehand.allocation.cycle_solver.solve_dual_active_set", boom)
    cs, J, com = antipodal()
    out = QPAllocator().allocate(cs, J, com)
    assert out.ok and out.solver == "dual_active_set"


def test_a_deadline_budgets_the_steps_by_their_measured_time():
    """Past the time left at the measured time per step the solve stops as a deadline cycle
    (no torque; the loop keeps the last one); with time to spare it is exact, and the measured
    time per step follows the solves."""
    cs, J, com = near_loss()
    hurried = QPAllocator(options=SolveOptions(deadline=1e-9, warm_start=False))
    out = hurried.allocate(cs, J, com)
    assert out.status is AllocationStatus.DEADLINE and out.tau is None
    assert hurried.last_solution.status == "deadline"
    relaxed = QPAllocator(options=SolveOptions(deadline=60.0, warm_start=False))
    before = relaxed.cycle_solver.step_ns
    assert relaxed.allocate(cs, J, com).fresh
    assert relaxed.last_solution.iterations > 100 and relaxed.cycle_solver.step_ns != before


def _farkas_ray(qp: AllocationQP) -> np.ndarray | None:
    """A ray proving ``qp`` infeasible, found independently by scipy's LP: signed row
    multipliers ``y`` (> 0 at a lower bound, < 0 at an upper one) with ``A^T y <= 0`` and
    ``lo . y+ + hi . y- = 1``; None when no ray exists (the problem is feasible)."""
    from scipy.optimize import linprog

    A, lo, hi = dense_rows(qp)
    low, up = np.flatnonzero(np.isfinite(lo)), np.flatnonzero(np.isfinite(hi))
    # Variables: y+ on the finite lower bounds, y- on the finite upper ones, both >= 0.
    ray_rows = np.hstack((A[low].T, -A[up].T))  # A^T y <= 0, so the bounds' z = -A^T y >= 0
    gap = np.r_[lo[low], -hi[up]]
    res = linprog(
        np.zeros(gap.size),
        A_ub=ray_rows,
        b_ub=np.zeros(qp.n_lambda),
        A_eq=gap[None],
        b_eq=[1.0],
        bounds=(0, None),
        method="highs",
    )
    if res.status != 0:
        return None
    y = np.zeros(lo.size)
    y[low] += res.x[: low.size]
    y[up] -= res.x[low.size :]
    return y


def test_a_farkas_ray_certifies_infeasibility_and_nothing_certifies_a_feasible_problem():
    cs, J, com = antipodal(lever=1.0)  # infeasible: the squeeze needs more than the limits
    qp = build_allocation_qp(cs, J, com, AllocationParams.checked("test"))
    A, _, lo, hi = allocation_rows(qp)
    y = _farkas_ray(qp)
    assert y is not None
    z = -dense_rows(qp)[0].T @ y  # the bounds' multipliers that close A^T y + z = 0
    assert (z >= -1e-12).all()
    assert infeasibility_certificate(qp, A, lo, hi, y, np.maximum(z, 0.0))
    assert not infeasibility_certificate(qp, A, lo, hi, -y, np.maximum(-z, 0.0))
    assert not infeasibility_certificate(qp, A, lo, hi, 0.0 * y, 0.0 * z)
    # A feasible problem has no ray, and its optimal multipliers are none.
    feasible = dict(PROBLEMS)["near loss"]
    assert _farkas_ray(feasible) is None
    A, _, lo, hi = allocation_rows(feasible)
    sol, y, _ = solve_dual_active_set(feasible)
    G = feasible.G_lam
    lam = sol.x[: feasible.n_lambda]
    z = G.T @ (G @ lam + feasible.w_ext) + feasible.params.reg * lam - dense_rows(feasible)[0].T @ y
    assert not infeasibility_certificate(feasible, A, lo, hi, y, np.maximum(z, 0.0))


def _kernel(qp: AllocationQP) -> tuple:
    """The compiled solve, cold, exactly as :func:`solve_dual_active_set` calls it."""
    A, qr, lo, hi = allocation_rows(qp)
    scale = das_module._row_scales(qp, A, lo.size, None)
    n, m = qp.n_lambda, lo.size
    G = np.ascontiguousarray(qp.G_lam)
    start = (np.zeros(n, bool), np.zeros(m, np.int8), das_module.TOL, das_module.MAX_STEPS)
    return dual_active_set(
        G, qp.w_ext, qp.params.reg, A, *qr, qp.W, qp.act_idx, lo, hi, scale, *start
    )


def diverging() -> tuple[ContactSet, np.ndarray, np.ndarray]:
    """A recorded cycle whose problem is infeasible although rounding hides it from the dual
    active-set steps (the extra-large clamp pulled by 90 deg, 2 contacts, ``wholehand bench
    cycle --worst``): its multipliers diverge instead of meeting a dependent constraint."""
    d = np.load(Path(__file__).parent / "data" / "diverging_allocation.npz")
    cs = contact_set(d["p_world"], d["n_world"], d["link"], d["link_actuated"], d["link_fingertip"])
    return cs, d["J_world"], d["p_com_world"]


def test_diverging_multipliers_are_certified_infeasible_without_the_fallback(monkeypatch):
    cs, J, com = diverging()
    qp = build_allocation_qp(cs, J, com, AllocationParams.checked("test"))
    A, _, lo, hi = allocation_rows(qp)
    lam, y, z, code, _, _ = _kernel(qp)
    assert code == NUMERICAL and np.abs(y).max() > DIVERGED  # the steps diverged
    assert infeasibility_certificate(qp, A, lo, hi, y, z)
    assert _farkas_ray(qp) is not None  # an LP agrees: no edge weights meet the rows
    sol, _, _ = solve_dual_active_set(qp)
    assert sol.status == "infeasible" and sol.x is None and "certified" in sol.detail
    daqp = solve_allocation(qp, make_solver("daqp"))
    assert daqp.status == "infeasible"

    def no_fallback(*args, **kwargs):
        raise AssertionError("the fallback solver was asked")

    monkeypatch.setattr("wholehand.allocation.cycle_solver.solve_allocation", no_fallback)
    out = QPAllocator().allocate(cs, J, com)
    assert out.status is AllocationStatus.INFEASIBLE and out.tau is None


def test_a_warm_start_that_fails_is_retried_cold_before_the_fallback(monkeypatch):
    import wholehand.allocation.solvers.dual_active_set as das

    calls: list[bool] = []

    def led_astray(qp, free=None, rows=None, scale=None, max_steps=das.MAX_STEPS):
        calls.append(free is not None)
        if free is not None:  # the warm solve fails as rounding can make it
            return das.solve_dual_active_set(qp, max_steps=1)
        return das.solve_dual_active_set(qp, max_steps=max_steps)

    monkeypatch.setattr("wholehand.allocation.cycle_solver.solve_dual_active_set", led_astray)
    cs, J, com = near_loss()
    alloc = QPAllocator()
    assert alloc.allocate(cs, J, com).fresh  # cold: no previous cycle
    out = alloc.allocate(cs, J, com)
    assert calls == [False, True, False]
    assert out.fresh and "dual active set" in alloc.last_solution.detail
    check_allocation(out, cs, J, com, alloc.params)
