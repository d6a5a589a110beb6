"""Force allocation QP (paper Sec. III-C): constraints, optimality, signs, fallbacks, plug-ins."""

from __future__ import annotations

import dataclasses
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import qpsolvers
from kernels_loaded import kernel_versions, loaded_since
from wholehand_plugins.fingertip_only import FingertipOnlyAllocator
from wholehand_plugins.qp import QPAllocator, QPNoConsistencyAllocator

from wholehand import registry
from wholehand.allocation import solve as solve_module
from wholehand.allocation.base import Allocation, AllocationStatus, hand_keywords
from wholehand.allocation.cycle_solver import SOLVE_SHARE
from wholehand.allocation.kernel_loading import load_kernels
from wholehand.allocation.kernels import sigma_min_lower_bound
from wholehand.allocation.null_space import ActuationNullSpace
from wholehand.allocation.options import SolveOptions
from wholehand.allocation.problem import (
    N_EDGES,
    AllocationParams,
    AllocationQP,
    build_allocation_qp,
    friction_edges,
)
from wholehand.allocation.reference import direct_problem, solved_problem
from wholehand.allocation.solve import binding_rows, dense_qp, solve_allocation
from wholehand.allocation.solvers import NATIVE_SOLVERS, available_solvers, make_solver
from wholehand.allocation.solvers.base import DenseQP, QPResult
from wholehand.bench.allocate import run_allocation_benchmark
from wholehand.bench.synthetic_grasps import synthetic_grasp
from wholehand.contacts.base import ContactSet
from wholehand.errors import ConfigError

# Native adapters plus every qpsolvers backend through the generic adapter.
SOLVERS = [
    "dual_active_set",
    *NATIVE_SOLVERS,
    *(f"qpsolvers:{s}" for s in qpsolvers.available_solvers),
]

TOL = 1e-6  # constraint tolerance of accepted solutions [N, N*m]

# (N contacts, seed, tau_max): feasible synthetic grasps where torque and consistency rows bind.
CASES = [(5, 0, 0.2), (8, 0, 0.2), (14, 2, 0.2), (14, 0, 0.05), (30, 1, 0.2)]


# ------------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------------


def contact_set(
    p: Any, n: Any, link: Any, link_actuated: Any, link_fingertip: Any = None
) -> ContactSet:
    link_actuated = np.asarray(link_actuated, dtype=bool)
    if link_fingertip is None:
        link_fingertip = np.zeros_like(link_actuated)
    p = np.asarray(p, dtype=float).reshape(-1, 3)
    return ContactSet(
        p_world=p,
        n_world=np.asarray(n, dtype=float).reshape(-1, 3),
        link=np.asarray(link, dtype=np.intp),
        distance=np.zeros(p.shape[0]),
        link_actuated=link_actuated,
        link_fingertip=np.asarray(link_fingertip, dtype=bool),
    )


def antipodal(lever: float = 0.01, d: float = 0.04) -> tuple[ContactSet, np.ndarray, np.ndarray]:
    """Two fingertips at +-d x pressing along x, each moved along x by its own joint."""
    cs = contact_set(
        [[d, 0, 0], [-d, 0, 0]],
        [[1, 0, 0], [-1, 0, 0]],
        [1, 2],
        [False, True, True],
        [False, True, True],
    )
    J = np.zeros((2, 3, 2))
    J[0, 0, 0] = lever
    J[1, 0, 1] = -lever
    return cs, J, np.zeros(3)


def settings_for(solver: str) -> dict[str, Any]:
    """Tight tolerances for qpsolvers-driven solvers."""
    if solver == "osqp":
        return {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 100000}
    base = solver.removeprefix("qpsolvers:")
    return {
        "osqp": {
            "eps_abs": 1e-9,
            "eps_rel": 1e-9,
            "polishing": True,
            "max_iter": 100000,
            "raise_error": False,
        },
        "daqp": {"primal_tol": 1e-10},
        "piqp": {"eps_abs": 1e-10, "eps_rel": 1e-10},
    }.get(base, {})


def objective(qp: AllocationQP, lam: np.ndarray) -> float:
    w = qp.G_lam @ lam
    return 0.5 * float(w @ w + qp.params.reg * lam @ lam)


def reference(qp: AllocationQP) -> tuple[float, qpsolvers.Solution]:
    """Optimal objective of the full (unscreened) problem, certified by KKT residuals."""
    sol = qpsolvers.solve_problem(solved_problem(qp), solver="daqp", primal_tol=1e-10)
    assert sol.found
    assert sol.primal_residual() < 1e-9
    assert sol.dual_residual() < 1e-9
    assert abs(sol.duality_gap()) < 1e-9
    return objective(qp, sol.x[: qp.n_lambda]), sol


def check_allocation(
    alloc: Allocation,
    cs: ContactSet,
    J: np.ndarray,
    com: np.ndarray,
    params: AllocationParams,
    tol: float = TOL,
) -> None:
    """Every constraint, recomputed from the outputs with independent formulas."""
    assert alloc.fresh and (alloc.status is AllocationStatus.OK) is alloc.balanced
    f = alloc.f_local
    assert np.isfinite(f).all() and np.isfinite(alloc.tau).all()
    assert (f[:, 0] >= -tol).all()
    assert (np.abs(f[:, 1]) + np.abs(f[:, 2]) <= params.mu * f[:, 0] + tol).all()
    assert f[:, 0].sum() >= params.f_n_min - tol
    # f_world = -n f_n + tangents; torque tau = sum over actuated contacts of J_i^T f_world_i.
    np.testing.assert_allclose((alloc.f_world * cs.n_world).sum(1), -f[:, 0], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(alloc.f_world, axis=1), np.linalg.norm(f, axis=1))
    act = cs.actuated
    tau = np.einsum("ncv,nc->v", J[act], alloc.f_world[act])
    np.testing.assert_allclose(alloc.tau, tau, atol=1e-9)
    assert (np.abs(alloc.tau) <= params.tau_max + tol).all()
    w = np.concatenate([alloc.f_world.sum(0), np.cross(cs.p_world - com, alloc.f_world).sum(0)])
    np.testing.assert_allclose(alloc.residual_wrench, w, atol=1e-9)
    if params.consistency:
        J_act = J[act].reshape(-1, J.shape[2])
        m, k = J_act.shape
        if m > k and np.linalg.svd(J_act, compute_uv=False).min() > params.svd_tol:
            N_u = np.linalg.svd(J_act)[0][:, k:]  # numpy's own SVD basis (ours up to signs)
        else:
            N_u = ActuationNullSpace(J_act, params.svd_tol).basis()
        assert (np.abs(N_u.T @ alloc.f_world[act].ravel()) <= params.eps_margin + tol).all()


# ------------------------------------------------------------------------------------------------
# optimality, constraints, solver agreement
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("case", CASES)
def test_reference_solutions_satisfy_kkt_for_every_solver(case: tuple[int, int, float]) -> None:
    n, seed, tmax = case
    cs, J, com = synthetic_grasp(seed, n).cycle()
    params = AllocationParams.checked("test", tau_max=tmax)
    qp = build_allocation_qp(cs, J, com, params)
    best, _ = reference(qp)
    for solver in qpsolvers.available_solvers:
        sparse = solver in qpsolvers.sparse_solvers and solver not in qpsolvers.dense_solvers
        sol = qpsolvers.solve_problem(
            solved_problem(qp, sparse=sparse), solver=solver, **settings_for(f"qpsolvers:{solver}")
        )
        assert sol.found, solver
        assert sol.primal_residual() < 1e-6, solver
        assert sol.dual_residual() < 1e-5, solver
        assert abs(sol.duality_gap()) < 1e-5, solver
        assert objective(qp, sol.x[: qp.n_lambda]) == pytest.approx(best, rel=1e-5, abs=1e-8)


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("case", CASES)
def test_allocator_optimum_and_constraints(solver: str, case: tuple[int, int, float]) -> None:
    n, seed, tmax = case
    cs, J, com = synthetic_grasp(seed, n).cycle()
    alloc = QPAllocator(
        tau_max=tmax, options=SolveOptions(solver=solver, solver_settings=settings_for(solver))
    )
    out = alloc.allocate(cs, J, com)
    check_allocation(out, cs, J, com, alloc.params)
    assert out.solver == solver and 0.0 < out.solver_time < out.solve_time
    qp = build_allocation_qp(cs, J, com, alloc.params)
    best, _ = reference(qp)
    lam = alloc.last_solution.x[: qp.n_lambda]
    assert objective(qp, lam) == pytest.approx(best, rel=1e-5, abs=1e-8)
    np.testing.assert_allclose(qp.f_local(lam), out.f_local)


@pytest.mark.parametrize("case", CASES)
def test_screening_is_exact(case: tuple[int, int, float]) -> None:
    n, seed, tmax = case
    cs, J, com = synthetic_grasp(seed, n).cycle()
    params = AllocationParams.checked("test", tau_max=tmax)
    qp = build_allocation_qp(cs, J, com, params)
    solver = make_solver("daqp")
    full = solve_allocation(qp, solver, screening=False)
    screened = solve_allocation(qp, solver, screening=True)
    capped = solve_allocation(qp, solver, screening=True, max_rounds=1)  # falls back to full
    assert screened.n_rows <= full.n_rows
    for sol in (full, screened, capped):
        assert sol.status == "optimal" and sol.violation < 1e-8
        np.testing.assert_allclose(sol.x, full.x, rtol=1e-6, atol=1e-7)


def _case_problems() -> list[tuple[str, AllocationQP]]:
    out = []
    for n, seed, tmax in CASES:
        cs, J, com = synthetic_grasp(seed, n).cycle()
        params = AllocationParams.checked("test", tau_max=tmax)
        out.append((f"synthetic {n}/{seed}/{tmax}", build_allocation_qp(cs, J, com, params)))
    cs, J, com = near_loss()
    out.append(("near loss", build_allocation_qp(cs, J, com, AllocationParams.checked("test"))))
    return out


@pytest.mark.parametrize("start", ["one edge", "every fourth edge", "random half"])
def test_edge_screening_is_exact(start: str) -> None:
    """From any starting set of edge weights the screened solve ends at the full problem's
    optimum: left-out edges are priced with the rows' multipliers and added when they would
    lower the objective (KKT of the full problem at the end)."""
    rng = np.random.default_rng(3)
    for name, qp in _case_problems():
        solver = make_solver("daqp")
        full = solve_allocation(qp, solver, screening=False)
        edges = {
            "one edge": np.array([0]),
            "every fourth edge": np.arange(0, qp.n_lambda, 4),
            "random half": np.flatnonzero(rng.random(qp.n_lambda) < 0.5),
        }[start]
        screened = solve_allocation(qp, make_solver("daqp"), edge_sel=edges)
        assert screened.status == "optimal", name
        assert screened.violation < 1e-8, name
        assert full.x is not None and screened.x is not None
        np.testing.assert_allclose(screened.x, full.x, rtol=1e-6, atol=1e-7, err_msg=name)


def test_edge_screening_keeps_the_problems_small_near_a_loss() -> None:
    cs, J, com = near_loss()
    qp = build_allocation_qp(cs, J, com, AllocationParams.checked("test"))
    full = solve_allocation(qp, make_solver("daqp"), screening=False)
    assert full.x is not None
    support = np.flatnonzero(full.x[: qp.n_lambda] > 1e-9)
    assert support.size < qp.n_lambda / 4  # most edge weights are zero at the optimum
    # Started from the optimum's support and binding rows (a cycle like the last one), one
    # small solve proves optimality.
    t, z = binding_rows(qp, full)
    sol = solve_allocation(qp, make_solver("daqp"), edge_sel=support, torque_sel=t, null_sel=z)
    assert sol.status == "optimal" and sol.rounds == 1 and sol.n_edges == support.size
    assert sol.x is not None
    np.testing.assert_allclose(sol.x, full.x, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize(
    "params",
    [{}, {"screen_edges": True}, {"screening": False}, {"solver": "dual_active_set"}],
    ids=["rows", "edges", "full", "dual active set"],
)
def test_a_built_allocator_loads_no_kernel_while_allocating(params: dict[str, Any]) -> None:
    """Every kernel version a cycle uses is loaded when the allocator is built, including those
    of several consistency rows at once (LAPACK returns their columns in Fortran order)."""
    cs, J, com = near_loss()
    alloc = QPAllocator(options=params)
    before = kernel_versions()
    out = alloc.allocate(cs, J, com)
    sol = alloc.last_solution
    assert out.fresh and sol is not None and sol.null_sel.size > 1
    assert loaded_since(before) == {}


def test_a_round_adding_edges_starts_from_the_last_rounds_solution() -> None:
    """Left-out edge weights sit at zero, so a round that adds them starts with their bounds
    active: the fallback to the full problem after one screening round then costs far fewer
    iterations than a cold solve of the full problem, and ends at its optimum."""
    cs, J, com = near_loss()
    qp = build_allocation_qp(cs, J, com, AllocationParams.checked("test"))
    full = solve_allocation(qp, make_solver("daqp"), screening=False)
    assert full.x is not None
    support = np.flatnonzero(full.x[: qp.n_lambda] > 1e-9)
    half = support[: support.size // 2]
    sol = solve_allocation(qp, make_solver("daqp"), edge_sel=half, max_rounds=1)
    assert sol.rounds == 2 and sol.n_edges == qp.n_lambda  # one screened round, then the full
    assert sol.x is not None and sol.violation < 1e-8
    np.testing.assert_allclose(sol.x, full.x, rtol=1e-6, atol=1e-7)
    assert sol.iterations < full.iterations / 2


class _DeadlineOnSecondSolve:
    """DAQP that runs out of time in the second solve of each allocation."""

    def __init__(self) -> None:
        self.inner = make_solver("daqp")
        self.calls = 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def solve(self, qp: Any, x0: Any = None, warm: bool = False, time_limit: Any = None) -> Any:
        self.calls += 1
        if self.calls % 2 == 0:
            return QPResult(None, "deadline", 0, "test")
        return self.inner.solve(qp, x0, warm, time_limit)


def test_a_deadline_cycle_hands_its_progress_to_the_next() -> None:
    cs, J, com = near_loss()
    alloc = QPAllocator(options=SolveOptions(solver="daqp", screen_edges=True, deadline=60.0))
    alloc.cycle_solver.qp_solver = _DeadlineOnSecondSolve()  # type: ignore[assignment]
    first = alloc.allocate(cs, J, com)
    assert first.status is AllocationStatus.DEADLINE and first.tau is None
    sol = alloc.last_solution
    assert sol is not None and sol.x_relaxed is not None and sol.rounds == 2
    # The next cycle starts from the first round's forces and the rows it found violated.
    warm = alloc.cycle_solver.warm
    assert warm.lam is not None
    np.testing.assert_array_equal(warm.lam.ravel(), sol.x_relaxed[: 4 * len(cs)])
    assert warm.torque_dofs.size + warm.null_rows.size > 0
    exact = QPAllocator(options=SolveOptions(solver="daqp", screen_edges=True)).allocate(cs, J, com)
    alloc.cycle_solver.qp_solver = make_solver("daqp")
    again = alloc.allocate(cs, J, com)
    assert again.fresh
    np.testing.assert_allclose(again.tau, exact.tau, rtol=1e-6, atol=1e-8)


def test_a_deadline_solution_carries_the_row_values_of_its_last_round() -> None:
    """The rows the next cycle starts with come from the values at the last finished round's
    solution, handed over rather than computed again: they must be exactly those values."""
    cs, J, com = near_loss()
    alloc = QPAllocator(options=SolveOptions(screen_edges=True))
    qp = build_allocation_qp(cs, J, com, alloc.params)
    every_edge = np.arange(qp.n_lambda, dtype=np.intp)
    sol = solve_allocation(qp, _DeadlineOnSecondSolve(), edge_sel=every_edge)  # type: ignore[arg-type]
    assert sol.status == "deadline" and sol.x_relaxed is not None and sol.rounds == 2
    lam = sol.x_relaxed[: qp.n_lambda]
    np.testing.assert_array_equal(sol.torque_values, qp.T_lam @ lam)
    assert qp.n_null > 0
    np.testing.assert_array_equal(sol.null_values, qp.null_values(lam))
    # A deadline before any round finished has no solution and no values.
    early = solve_allocation(qp, make_solver("daqp"), deadline_ns=0)
    assert early.x_relaxed is None and early.torque_values.size == early.null_values.size == 0


class _TimeLimits:
    """DAQP that records the time limit of each solve."""

    def __init__(self) -> None:
        self.inner = make_solver("daqp")
        self.limits: list[float] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def solve(self, qp: Any, x0: Any = None, warm: bool = False, time_limit: Any = None) -> Any:
        self.limits.append(time_limit)
        return self.inner.solve(qp, x0, warm, time_limit)


def test_the_solver_gets_its_share_of_the_deadline() -> None:
    cs, J, com = near_loss()
    alloc = QPAllocator(options=SolveOptions(solver="daqp", deadline=10.0))
    alloc.cycle_solver.qp_solver = solver = _TimeLimits()  # type: ignore[assignment]
    assert alloc.allocate(cs, J, com).fresh
    # Each round's limit is what is left of SOLVE_SHARE of the budget once it is built.
    assert solver.limits and all(0.0 < t <= 10.0 * SOLVE_SHARE for t in solver.limits)
    assert solver.limits[0] > 10.0 * SOLVE_SHARE - 0.5
    assert all(a > b for a, b in pairwise(solver.limits))


class _MissFirst(_TimeLimits):
    """DAQP that records each solve's time limit and runs out of time in the first solve."""

    def __init__(self) -> None:
        super().__init__()
        self.missed = False

    def solve(self, qp: Any, x0: Any = None, warm: bool = False, time_limit: Any = None) -> Any:
        self.limits.append(time_limit)
        if not self.missed:
            self.missed = True
            return QPResult(None, "deadline", 0, "test")
        return self.inner.solve(qp, x0, warm, time_limit)


def test_the_allocation_after_a_missed_deadline_gets_the_longer_budget() -> None:
    cs, J, com = near_loss()
    options = SolveOptions(solver="daqp", deadline=10.0, deadline_after_miss=30.0)
    alloc = QPAllocator(options=options)
    alloc.cycle_solver.qp_solver = solver = _MissFirst()  # type: ignore[assignment]
    assert alloc.allocate(cs, J, com).status is AllocationStatus.DEADLINE
    assert 10.0 * SOLVE_SHARE - 0.5 < solver.limits[0] <= 10.0 * SOLVE_SHARE
    solver.limits.clear()
    assert alloc.allocate(cs, J, com).fresh  # the one after the miss
    assert 30.0 * SOLVE_SHARE - 0.5 < solver.limits[0] <= 30.0 * SOLVE_SHARE
    solver.limits.clear()
    assert alloc.allocate(cs, J, com).fresh  # back to the deadline
    assert 10.0 * SOLVE_SHARE - 0.5 < solver.limits[0] <= 10.0 * SOLVE_SHARE
    assert (
        QPAllocator(options=SolveOptions(deadline=10.0)).options.deadline_after_miss == 10.0
    )  # None: the same budget


@pytest.mark.parametrize(
    ("deadline", "after_miss"), [(None, 0.003), (0.002, 0.001), (0.002, float("inf"))]
)
def test_the_budget_after_a_miss_needs_a_deadline_it_does_not_undercut(
    deadline: float | None, after_miss: float
) -> None:
    with pytest.raises(ConfigError, match="deadline_after_miss=.* at least deadline"):
        QPAllocator(options=SolveOptions(deadline=deadline, deadline_after_miss=after_miss))


def test_warm_start_matches_cold_over_a_control_sequence() -> None:
    grasp = synthetic_grasp(2, 14)
    rng = np.random.default_rng(5)
    warm, cold = QPAllocator(), QPAllocator(options=SolveOptions(warm_start=False))
    for _ in range(15):
        cs, J, com = grasp.cycle(rng, 2e-4)
        a, b = warm.allocate(cs, J, com), cold.allocate(cs, J, com)
        check_allocation(a, cs, J, com, warm.params)
        np.testing.assert_allclose(a.f_local, b.f_local, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(a.tau, b.tau, rtol=1e-6, atol=1e-8)
    assert warm.counts[AllocationStatus.OK] == 15


@pytest.mark.parametrize(
    ("warm", "ref"),
    [
        ({}, {"warm_start": False}),
        # With the edge weights screened too, against the unscreened full problem.
        ({"screen_edges": True}, {"warm_start": False, "screening": False}),
    ],
)
def test_warm_start_survives_contact_changes(warm: dict[str, Any], ref: dict[str, Any]) -> None:
    grasp = synthetic_grasp(0, 30)
    rng = np.random.default_rng(1)
    alloc, reference = QPAllocator(options=warm), QPAllocator(options=ref)
    for k in range(12):
        cs, J, com = grasp.cycle(rng, 1e-4)
        keep = rng.random(len(cs)) > 0.2 if k % 3 else np.ones(len(cs), bool)
        cs, J = cs.select(keep), J[keep]
        a, b = alloc.allocate(cs, J, com), reference.allocate(cs, J, com)
        assert a.status is b.status
        if a.ok:
            check_allocation(a, cs, J, com, alloc.params)
            np.testing.assert_allclose(a.tau, b.tau, rtol=1e-5, atol=1e-7)


# ------------------------------------------------------------------------------------------------
# analytic cases
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("solver", SOLVERS)
def test_symmetric_antipodal_pair(solver: str) -> None:
    cs, J, com = antipodal()
    alloc = QPAllocator(options=SolveOptions(solver=solver, solver_settings=settings_for(solver)))
    out = alloc.allocate(cs, J, com)
    check_allocation(out, cs, J, com, alloc.params)
    np.testing.assert_allclose(out.residual_wrench, 0.0, atol=1e-7)
    np.testing.assert_allclose(out.f_local[:, 0], [5.0, 5.0], rtol=1e-5)
    assert out.f_local[:, 0].sum() == pytest.approx(10.0, rel=1e-6)
    np.testing.assert_allclose(out.f_local[:, 1:], 0.0, atol=1e-5)
    np.testing.assert_allclose(out.f_world, [[-5, 0, 0], [5, 0, 0]], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(out.tau, [-0.05, -0.05], rtol=1e-5)


@pytest.mark.parametrize("q", [0.0, 0.3, -1.2])
@pytest.mark.parametrize("behind", [False, True])
def test_torque_sign_by_virtual_work_on_one_link(q: float, behind: bool) -> None:
    """tau * dq equals the work f . dp the hand does on the object (finite differences)."""
    L = 0.05

    def point(q: float) -> np.ndarray:  # revolute joint about world z at the origin
        return L * np.array([np.cos(q), np.sin(q), 0.0])

    h = 1e-6
    dp = (point(q + h) - point(q - h)) / (2 * h)
    # The object sits where the link moves to (or behind it); its normal faces the link.
    n = -dp / np.linalg.norm(dp) * (-1.0 if behind else 1.0)
    cs = contact_set(point(q), n, [1], [False, True], [False, True])
    alloc = QPAllocator(f_n_min=1.0)
    out = alloc.allocate(cs, dp.reshape(1, 3, 1), np.array([0.0, 0.3, 0.0]))
    check_allocation(out, cs, dp.reshape(1, 3, 1), np.array([0.0, 0.3, 0.0]), alloc.params)
    assert out.f_local[0, 0] == pytest.approx(1.0, rel=1e-6)
    dq = 1e-4
    work = out.f_world[0] @ (point(q + dq) - point(q))
    assert out.tau[0] * dq == pytest.approx(work, rel=1e-3)
    assert out.tau[0] == pytest.approx(-L if behind else L, rel=1e-6)


def build_null_case() -> tuple[ContactSet, np.ndarray, np.ndarray]:
    """Contact 1's joint moves it tangentially (along y): its normal push is invisible to tau."""
    cs, J, com = antipodal()
    J[0] = 0.0
    J[0, 1, 0] = 0.01
    return cs, J, com


def test_consistency_bounds_null_space_components() -> None:
    cs, J, com = build_null_case()
    on = QPAllocator()
    out = on.allocate(cs, J, com)
    check_allocation(out, cs, J, com, on.params)
    N_u = ActuationNullSpace(J.reshape(6, 2)).basis()
    null = N_u.T @ out.f_world.ravel()
    assert np.abs(null).max() == pytest.approx(0.5, abs=1e-6)  # the bound binds
    assert np.linalg.norm(out.residual_wrench) > 1.0  # balance is given up for consistency


def test_without_consistency_the_null_space_bound_is_exceeded() -> None:
    cs, J, com = build_null_case()
    off = QPNoConsistencyAllocator()
    assert not off.params.consistency
    out = off.allocate(cs, J, com)
    check_allocation(out, cs, J, com, off.params)
    np.testing.assert_allclose(out.residual_wrench, 0.0, atol=1e-7)
    N_u = ActuationNullSpace(J.reshape(6, 2)).basis()
    assert np.abs(N_u.T @ out.f_world.ravel()).max() > 0.5 + 1.0


def test_passive_palm_contact_is_in_the_wrench_but_not_in_tau() -> None:
    cs = contact_set([[0.04, 0, 0], [-0.04, 0, 0]], [[1, 0, 0], [-1, 0, 0]], [0, 1], [False, True])
    J = np.zeros((2, 3, 1))
    J[1, 0, 0] = 0.01
    J[0, 1, 0] = 5.0  # a palm Jacobian must not leak into the torque
    out = QPAllocator().allocate(cs, J, np.zeros(3))
    np.testing.assert_allclose(out.f_local[:, 0], [5.0, 5.0], rtol=1e-5)
    np.testing.assert_allclose(out.tau, [0.01 * 5.0], rtol=1e-5)


# ------------------------------------------------------------------------------------------------
# reformulation and null-space basis
# ------------------------------------------------------------------------------------------------


def test_pyramid_edges_span_exactly_the_friction_pyramid() -> None:
    rng = np.random.default_rng(0)
    for mu in (0.0, 0.3, 0.7, 1.5):
        E = friction_edges(mu)
        lam = rng.random((200, 4)) * (rng.random((200, 4)) > 0.3)
        f = lam @ E.T
        assert (f[:, 0] >= 0).all()
        assert (np.abs(f[:, 1]) + np.abs(f[:, 2]) <= mu * f[:, 0] + 1e-12).all()
        if mu == 0.0:
            continue
        # Any pyramid point has a non-negative edge decomposition (constructive proof).
        fn = rng.random(200) * 5
        frac = rng.random((200, 2))
        frac /= np.maximum(1.0, frac.sum(1, keepdims=True))
        ft = mu * fn[:, None] * frac * rng.choice([-1.0, 1.0], size=(200, 2))
        s = fn - np.abs(ft).sum(1) / mu
        dec = np.stack(
            [
                np.maximum(ft[:, 0], 0) / mu + s / 4,
                np.maximum(-ft[:, 0], 0) / mu + s / 4,
                np.maximum(ft[:, 1], 0) / mu + s / 4,
                np.maximum(-ft[:, 1], 0) / mu + s / 4,
            ],
            axis=1,
        )
        assert (dec >= -1e-12).all()
        np.testing.assert_allclose(dec @ E.T, np.column_stack([fn, ft]), atol=1e-12)


@pytest.mark.parametrize("case", CASES)
def test_edge_form_equals_direct_form(case: tuple[int, int, float]) -> None:
    n, seed, tmax = case
    cs, J, com = synthetic_grasp(seed, n).cycle()
    params = AllocationParams.checked("test", tau_max=tmax, reg=1e-8)
    qp = build_allocation_qp(cs, J, com, params)
    direct, edge = direct_problem(qp), solved_problem(qp)
    # Same non-pyramid rows: direct rows composed with f = blockdiag(E) lambda are the edge rows.
    Eb = np.kron(np.eye(qp.n_contacts), friction_edges(params.mu))
    np.testing.assert_allclose(direct.G[4 * n :] @ Eb, edge.G[:, : qp.n_lambda], atol=1e-12)
    np.testing.assert_allclose(direct.h[4 * n :], edge.h)
    # Same optimal residual 1/2 ||G f||^2 (the ridges differ; reg is tiny here).
    sd = qpsolvers.solve_problem(direct, solver="daqp", primal_tol=1e-10)
    se = qpsolvers.solve_problem(edge, solver="daqp", primal_tol=1e-10)
    assert sd.found and se.found
    lam = se.x[: qp.n_lambda]
    res_d = 0.5 * np.sum((qp.G @ sd.x) ** 2)
    res_e = 0.5 * np.sum((qp.G_lam @ lam) ** 2)
    assert res_e == pytest.approx(res_d, rel=1e-4, abs=1e-7)
    # And each optimum is feasible for the other form.
    assert qp.violation(lam) < 1e-8
    f = qp.f_local(lam).ravel()
    assert (direct.G @ f - direct.h).max() < 1e-8


def test_null_space_basis_is_numpys_svd_basis_when_full_rank() -> None:
    rng = np.random.default_rng(4)
    for m, k in ((9, 4), (30, 16), (61, 16)):
        J = rng.normal(size=(m, k))
        ns = ActuationNullSpace(J)
        U = np.linalg.svd(J)[0][:, k:]
        assert ns.rank == k and ns.dim == m - k
        np.testing.assert_allclose(np.abs(U.T @ ns.basis()), np.eye(m - k), atol=1e-10)
        v = rng.normal(size=m)
        np.testing.assert_allclose(np.abs(ns.project(v)), np.abs(U.T @ v), atol=1e-12)


def test_rank_certificate_bounds_the_smallest_singular_value() -> None:
    rng = np.random.default_rng(11)
    for cond in (1.0, 1e3, 1e8, 1e14):
        for _ in range(20):
            U, _ = np.linalg.qr(rng.normal(size=(16, 16)))
            V, _ = np.linalg.qr(rng.normal(size=(16, 16)))
            s = np.geomspace(1.0, 1.0 / cond, 16)
            R = np.linalg.qr((U * s) @ V.T)[1]
            bound = sigma_min_lower_bound(
                np.asfortranarray(R + np.tril(rng.normal(size=(16, 16)), -1)), 16
            )
            sigma_min = np.linalg.svd(R, compute_uv=False).min()
            assert bound <= sigma_min * (1.0 + 1e-12)
            assert bound >= sigma_min / 4.0  # 1/||R^-1||_F >= sigma_min / sqrt(k)
    assert sigma_min_lower_bound(np.triu(np.ones((3, 3))) - np.diag([0.0, 1.0, 0.0]), 3) == 0.0


def test_rank_near_the_tolerance_is_the_svds() -> None:
    rng = np.random.default_rng(12)
    U, _ = np.linalg.qr(rng.normal(size=(30, 6)))
    V, _ = np.linalg.qr(rng.normal(size=(6, 6)))
    for smallest, rank in ((1.0005e-6, 6), (0.9995e-6, 5)):  # inside the certificate's margin
        ns = ActuationNullSpace((U * np.r_[np.ones(5), smallest]) @ V.T, svd_tol=1e-6)
        assert ns.rank == rank and ns.dim == 30 - rank
        assert np.count_nonzero(ns.singular_values > 1e-6) == rank


@pytest.mark.parametrize(
    "shape_rank", [((12, 6), 3), ((12, 6), 6), ((6, 9), 6), ((6, 9), 2), ((6, 3), 0)]
)
def test_null_space_basis_rank_deficient_and_wide(shape_rank: tuple[tuple[int, int], int]) -> None:
    (m, k), r = shape_rank
    rng = np.random.default_rng(7)
    J = rng.normal(size=(m, r)) @ rng.normal(size=(r, k)) if r else np.zeros((m, k))
    J[:, 0] = 0.0 if r < k else J[:, 0]  # an untouched joint
    r = np.linalg.matrix_rank(J)
    ns = ActuationNullSpace(J)
    B = ns.basis()
    assert ns.rank == r and B.shape == (m, m - r)
    np.testing.assert_allclose(B.T @ B, np.eye(m - r), atol=1e-10)
    np.testing.assert_allclose(J.T @ B, 0.0, atol=1e-10)
    v = rng.normal(size=m)
    np.testing.assert_allclose(ns.project(v), B.T @ v, atol=1e-12)
    idx = np.array([m - r - 1, 0]) if m > r else np.zeros(0, np.intp)
    np.testing.assert_allclose(ns.columns(idx), B[:, idx], atol=1e-12)


# ------------------------------------------------------------------------------------------------
# fallbacks
# ------------------------------------------------------------------------------------------------


def test_empty_contact_set_gives_zero_torque() -> None:
    alloc = QPAllocator()
    cs = ContactSet.empty(np.array([False, True]), np.array([False, True]))
    out = alloc.allocate(cs, np.zeros((0, 3, 5)), np.zeros(3))
    assert out.status is AllocationStatus.EMPTY and not out.ok
    assert out.tau.shape == (5,) and not out.tau.any()
    assert out.f_local.shape == (0, 3) and out.f_world.shape == (0, 3)
    assert out.residual_wrench.shape == (6,)


def test_contacts_without_actuated_link_give_zero_torque() -> None:
    cs = contact_set([[0.04, 0, 0]], [[1, 0, 0]], [0], [False, True])
    out = QPAllocator().allocate(cs, np.ones((1, 3, 3)), np.zeros(3))
    assert out.status is AllocationStatus.NO_ACTUATED_CONTACT
    assert out.tau.shape == (3,) and not out.tau.any()
    assert out.f_local.shape == (1, 3)


def test_infeasible_gives_no_torque() -> None:
    """A failed allocation has no torque (``tau is None``): keeping the last feasible one is
    the loop's job (tests/test_loop.py), so there is one memory of it."""
    alloc = QPAllocator()
    cs, J, com = antipodal(lever=0.01)
    first = alloc.allocate(cs, J, com)
    assert first.ok
    # Lever 1 m: 10 N of squeeze needs 5 N*m > tau_max at both joints.
    bad = alloc.allocate(cs, J * 100.0, com)
    assert bad.status is AllocationStatus.INFEASIBLE and bad.tau is None
    assert not bad.f_local.any()
    again = alloc.allocate(cs, J * 100.0, com)
    assert again.tau is None
    assert alloc.counts[AllocationStatus.INFEASIBLE] == 2
    assert alloc.allocate(cs, J, com).ok  # recovers
    fresh = QPAllocator(tau_max=1e-3, f_n_min=50.0)
    out = fresh.allocate(cs, J, com)
    assert out.status is AllocationStatus.INFEASIBLE and out.tau is None


@pytest.mark.parametrize("solver", SOLVERS)
def test_infeasible_for_every_solver_never_raises(solver: str) -> None:
    cs, J, com = antipodal(lever=1.0)
    out = QPAllocator(options=SolveOptions(solver=solver)).allocate(cs, J, com)
    assert out.status in (AllocationStatus.INFEASIBLE, AllocationStatus.SOLVER_FAILED)
    assert out.tau is None


def test_solver_failure_and_nan_input_give_no_torque() -> None:
    grasp = synthetic_grasp(2, 14)
    cs, J, com = grasp.cycle()
    alloc = QPAllocator()
    first = alloc.allocate(cs, J, com)
    assert first.ok
    J_nan = J.copy()
    J_nan[3, 1, 2] = np.nan
    out = alloc.allocate(cs, J_nan, com)
    assert out.status is AllocationStatus.SOLVER_FAILED and out.tau is None
    for bad_com in (np.r_[com[:2], np.inf], np.r_[np.nan, com[1:]]):
        out = alloc.allocate(cs, J, bad_com)
        assert out.status is AllocationStatus.SOLVER_FAILED and out.tau is None
    p_nan = cs.p_world.copy()
    p_nan[0, 2] = np.nan
    out = alloc.allocate(dataclasses.replace(cs, p_world=p_nan), J, com)
    assert out.status is AllocationStatus.SOLVER_FAILED and out.tau is None
    starved = QPAllocator(options=SolveOptions(solver="daqp", solver_settings={"iter_limit": 1}))
    out = starved.allocate(cs, J, com)
    assert out.status is AllocationStatus.SOLVER_FAILED and out.tau is None
    assert alloc.allocate(cs, J, com).ok


def test_forces_that_cannot_balance_are_unbalanced_but_applied() -> None:
    """One fingertip pressing +x with a 10 N squeeze: nothing opposes it, so the least
    residual is the squeeze itself (10 N along the normal) and the torque is lever * 10 N."""
    cs = contact_set([[0.04, 0, 0]], [[1, 0, 0]], [1], [False, True], [False, True])
    J = np.zeros((1, 3, 1))
    J[0, 0, 0] = 0.01
    out = QPAllocator(f_n_min=10.0).allocate(cs, J, np.zeros(3))
    assert out.status is AllocationStatus.UNBALANCED and out.fresh and not out.ok
    assert np.linalg.norm(out.residual_wrench[:3]) == pytest.approx(10.0, rel=1e-6)
    assert out.f_local[0, 0] == pytest.approx(10.0, rel=1e-6)
    np.testing.assert_allclose(np.abs(out.tau), [0.1], rtol=1e-6)


class Inflated:
    """A solver whose answers are too large by a factor ``1 + excess``."""

    def __init__(self, inner: Any, excess: float) -> None:
        self.inner, self.excess = inner, excess

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def solve(self, *args: Any, **kwargs: Any) -> QPResult:
        res = self.inner.solve(*args, **kwargs)
        x = None if res.x is None else res.x * (1.0 + self.excess)
        return dataclasses.replace(res, x=x)


@pytest.mark.parametrize("scale", [1e-4, 1.0, 1e3])
def test_the_feasibility_tolerance_is_relative_to_each_limit(scale: float) -> None:
    """The antipodal pair with its torque limits exactly binding (5 N per contact at a 1 cm
    lever, scaled): an answer 0.1 % over the limits is inaccurate at every scale, one 0.001 %
    over is accepted at every scale (an absolute tolerance gets one end wrong)."""
    cs, J, com = antipodal(lever=0.01)
    options = {"solver": "daqp", "warm_start": False}
    params = {"f_n_min": 10.0 * scale, "tau_max": 0.05 * scale, "options": options}
    for excess, status in ((1e-3, AllocationStatus.INACCURATE), (1e-5, AllocationStatus.OK)):
        alloc = QPAllocator(**params)
        alloc.cycle_solver.qp_solver = Inflated(alloc.cycle_solver.qp_solver, excess)  # type: ignore[assignment]
        out = alloc.allocate(cs, J, com)
        sol = alloc.last_solution
        assert sol is not None
        assert sol.relative_violation == pytest.approx(excess, rel=1e-3)
        assert out.status is status, (scale, excess)
        assert (out.tau is None) is (status is AllocationStatus.INACCURATE)


def test_reset_forgets_warm_start_and_counts() -> None:
    cs, J, com = antipodal()
    alloc = QPAllocator()
    alloc.allocate(cs, J, com)
    alloc.reset()
    assert not alloc.counts and alloc.last_solution is None
    assert alloc.allocate(cs, J * 100, com).tau is None


# ------------------------------------------------------------------------------------------------
# joints, plug-ins, configuration
# ------------------------------------------------------------------------------------------------


def test_actuated_dofs_mask_zeroes_other_joints() -> None:
    grasp = synthetic_grasp(0, 14)
    cs, J, com = grasp.cycle()
    mask = np.ones(16, bool)
    mask[[0, 5]] = False
    for dofs in (mask, np.flatnonzero(mask)):
        alloc = QPAllocator(actuated_dofs=dofs, tau_max=np.linspace(0.1, 0.3, 16))
        out = alloc.allocate(cs, J, com)
        assert out.ok
        assert out.tau[0] == 0.0 and out.tau[5] == 0.0
        f = out.f_world[cs.actuated]
        np.testing.assert_allclose(
            out.tau[mask], np.einsum("ncv,nc->v", J[cs.actuated][:, :, mask], f), atol=1e-10
        )
        assert (np.abs(out.tau) <= np.linspace(0.1, 0.3, 16) + TOL).all()


def test_fingertip_only_uses_distal_contacts() -> None:
    grasp = synthetic_grasp(1, 30)
    cs, J, com = grasp.cycle()
    tips = cs.fingertip
    assert 0 < tips.sum() < len(cs)
    out = FingertipOnlyAllocator().allocate(cs, J, com)
    ref = QPAllocator().allocate(cs.select(tips), J[tips], com)
    assert out.status is ref.status
    assert out.f_local.shape == (len(cs), 3) and out.f_world.shape == (len(cs), 3)
    assert not out.f_local[~tips].any() and not out.f_world[~tips].any()
    np.testing.assert_allclose(out.f_local[tips], ref.f_local)
    np.testing.assert_allclose(out.tau, ref.tau)
    palm_only = cs.select(~tips)
    empty = FingertipOnlyAllocator().allocate(palm_only, J[~tips], com)
    assert empty.status is AllocationStatus.EMPTY and empty.f_local.shape == (len(palm_only), 3)


def test_plugin_docstrings_have_one_line_descriptions() -> None:
    for cls in (QPAllocator, QPNoConsistencyAllocator, FingertipOnlyAllocator):
        first = (cls.__doc__ or "").strip().splitlines()[0]
        assert first and first.endswith(".") and len(first) < 100


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"mu": -0.1}, "mu"),
        ({"mu": float("nan")}, "mu"),
        ({"f_n_min": -1.0}, "f_n_min"),
        ({"tau_max": 0.0}, "tau_max"),
        ({"tau_max": -0.2}, "tau_max"),
        ({"tau_max": [0.2, 0.0]}, "tau_max"),
        ({"tau_max": [[0.2]]}, "tau_max"),
        ({"tau_max": "big"}, "tau_max"),
        ({"eps_margin": -0.5}, "eps_margin"),
        ({"svd_tol": 0.0}, "svd_tol"),
        ({"reg": 0.0}, "reg"),
        ({"reg": float("inf")}, "reg"),
        ({"actuated_dofs": [0, 0]}, "actuated_dofs"),
        ({"actuated_dofs": [-1]}, "actuated_dofs"),
        ({"actuated_dofs": [0.5]}, "actuated_dofs"),
        ({"options": {"feas_tol": -1.0}}, "feas_tol"),
        ({"options": {"solver": "no_such_solver"}}, "solver"),
        ({"options": {"solver_settings": 3}}, "solver_settings"),
        ({"options": {"no_such_option": 1}}, "no_such_option"),
        ({"options": 3}, "options"),
    ],
)
@pytest.mark.parametrize("cls", [QPAllocator, QPNoConsistencyAllocator, FingertipOnlyAllocator])
def test_bad_configuration_raises(kwargs: dict[str, Any], name: str, cls: type) -> None:
    with pytest.raises(ConfigError) as err:
        cls(**kwargs)
    assert cls.__name__ in str(err.value) and name in str(err.value)


@pytest.mark.parametrize("solver", [*NATIVE_SOLVERS, "qpsolvers:daqp"])
def test_bad_solver_settings_raise_at_construction(solver: str) -> None:
    with pytest.raises(ConfigError, match="solver_settings"):
        QPAllocator(options=SolveOptions(solver=solver, solver_settings={"no_such_setting_xyz": 1}))


def test_solver_exception_in_the_loop_becomes_a_status() -> None:
    cs, J, com = antipodal()
    alloc = QPAllocator(options=SolveOptions(solver="daqp"))
    first = alloc.allocate(cs, J, com)

    def boom(*args: Any) -> None:
        raise RuntimeError("solver crashed")

    alloc.cycle_solver.qp_solver._solve = boom  # type: ignore[method-assign]
    out = alloc.allocate(cs, J, com)
    assert first.ok and out.status is AllocationStatus.SOLVER_FAILED and out.tau is None


def test_unknown_solver_lists_installed_ones() -> None:
    with pytest.raises(ConfigError, match="daqp"):
        QPAllocator(options=SolveOptions(solver="gurobi_but_not_installed"))
    assert set(NATIVE_SOLVERS) <= set(available_solvers())


def test_shape_mismatches_raise() -> None:
    cs, J, com = antipodal()
    alloc = QPAllocator()
    with pytest.raises(ConfigError, match="J_world"):
        alloc.allocate(cs, J[:1], com)
    with pytest.raises(ConfigError, match="J_world"):
        alloc.allocate(cs, J[:, :2], com)
    with pytest.raises(ConfigError, match="p_com_world"):
        alloc.allocate(cs, J, np.zeros(2))
    with pytest.raises(ConfigError, match="tau_max"):
        QPAllocator(tau_max=[0.2, 0.2, 0.2]).allocate(cs, J, com)
    with pytest.raises(ConfigError, match="actuated_dofs"):
        QPAllocator(actuated_dofs=[3]).allocate(cs, J, com)
    with pytest.raises(ConfigError, match="J_world"):
        FingertipOnlyAllocator().allocate(cs, J[:1], com)


def test_benchmark_runs_and_writes_plot(tmp_path: Any) -> None:
    report = run_allocation_benchmark(
        contact_counts=(6, 12),
        solvers=["daqp"],
        cycles=3,
        warmup=1,
        out_dir=tmp_path,
        direct_solvers=("daqp", "no-such-solver"),
    )
    assert (tmp_path / "allocate.png").stat().st_size > 0
    assert (tmp_path / "allocate.json").exists()
    assert {r["mode"] for r in report["results"]} == {"warm", "no_warm_start", "cold"}
    assert set(report["best"]) == {"6", "12"}
    assert all(r["n"] == 3 for r in report["results"])
    # The yardstick: the direct form, installed solvers only, and the ratio of the p50s.
    assert [(r["solver"], r["n_contacts"], r["found"]) for r in report["direct"]] == [
        ("daqp", 6, 3),
        ("daqp", 12, 3),
    ]
    for n, row in report["speedup"].items():
        direct = next(r for r in report["direct"] if r["n_contacts"] == int(n))
        assert row["ratio"] == round(direct["p50_us"] / report["best"][n]["p50_us"], 2)
        # The paper lab's form (forces and wrench as variables, OSQP), p50 and p99.
        paper = next(r for r in report["paper_form"] if r["n_contacts"] == int(n))
        assert paper["solver"] == "osqp" and paper["n"] == 3
        best = report["best"][n]
        assert row["paper_ratio_p50"] == round(paper["p50_us"] / best["p50_us"], 2)
        assert row["paper_ratio_p99"] == round(paper["p99_us"] / best["p99_us"], 2)
    assert N_EDGES == 4


# ------------------------------------------------------------------------------------------------
# a known external wrench (the object's weight)
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("weight", "f_n_each"), [(2.0, 5.0), (10.0, 5.0 / 0.7)])
def test_weight_is_carried_by_friction_and_squeeze_grows_when_needed(
    weight: float, f_n_each: float
) -> None:
    # Two antipodal fingertips along x hold a weight along -z: each carries half by friction.
    # 2 N fits in the 10 N squeeze (0.7 * 5 N = 3.5 N per contact); 10 N needs f_n = 5 / 0.7
    # per contact, since the pyramid allows |f_z| <= mu f_n. These fingers move along x only,
    # so actuation consistency would cap their z forces at eps_margin: it is off here.
    cs, J, com = antipodal()
    alloc = QPAllocator(
        consistency=False, options=SolveOptions(solver="daqp", solver_settings=settings_for("daqp"))
    )
    w_ext = np.array([0.0, 0.0, -weight, 0.0, 0.0, 0.0])
    out = alloc.allocate(cs, J, com, external_wrench=w_ext)
    assert out.status is AllocationStatus.OK
    # Balanced up to the ridge's price (reg * lambda, see wholehand.allocation.problem).
    np.testing.assert_allclose(out.residual_wrench, 0.0, atol=2e-5)
    np.testing.assert_allclose(out.f_world[:, 2], [weight / 2, weight / 2], atol=2e-5)
    np.testing.assert_allclose(out.f_local[:, 0], [f_n_each, f_n_each], rtol=1e-4)
    np.testing.assert_allclose(out.tau, [-0.01 * f_n_each, -0.01 * f_n_each], rtol=1e-4)


@pytest.mark.parametrize("case", CASES[:3])
def test_edge_form_equals_direct_form_with_a_weight(case: tuple[int, int, float]) -> None:
    n, seed, tmax = case
    cs, J, com = synthetic_grasp(seed, n).cycle()
    w_ext = np.array([0.0, 0.0, -1.5, 0.01, 0.0, 0.0])
    params = AllocationParams.checked("test", tau_max=tmax, reg=1e-8)
    qp = build_allocation_qp(cs, J, com, params, w_ext=w_ext)
    edge = qpsolvers.solve_problem(solved_problem(qp), solver="daqp", primal_tol=1e-10)
    direct = qpsolvers.solve_problem(direct_problem(qp), solver="daqp", primal_tol=1e-10)
    assert edge.found and direct.found
    lam = edge.x[: qp.n_lambda]
    f = direct.x.reshape(-1, 3)
    np.testing.assert_allclose(edge.x[qp.n_lambda :], qp.G_lam @ lam + w_ext, atol=1e-8)
    w_edge = qp.G_lam @ lam + w_ext
    w_direct = qp.G @ direct.x + w_ext
    # The residual parts of the two optima agree up to the ridge's bound (module docstring).
    assert abs(w_edge @ w_edge - w_direct @ w_direct) < 1e-4
    assert f[:, 0].sum() >= params.f_n_min - 1e-6


def test_weight_needs_an_allocator_that_can_balance_it(allegro) -> None:
    from wholehand.loop.regulation import ForceRegulation
    from wholehand.models.objects import ObjectModel

    cube = ObjectModel.box((0.05, 0.05, 0.05))
    feedforward = registry.load("allocators", "feedforward")
    with pytest.raises(ConfigError, match="cannot balance the object's weight"):
        ForceRegulation(allegro, cube, None, feedforward, weight=(0, 0, -1))  # type: ignore[arg-type]
    qp = registry.load("allocators", "qp")
    with pytest.raises(ConfigError, match="weight must be 3 finite numbers"):
        ForceRegulation(allegro, cube, None, qp, weight=(0.0, -1.0))  # type: ignore[arg-type]


@pytest.mark.parametrize("case", CASES)
def test_a_passed_deadline_stops_screening_and_gives_no_torque(
    case: tuple[int, int, float],
) -> None:
    n, seed, tmax = case
    cs, J, com = synthetic_grasp(seed, n).cycle()
    qp = build_allocation_qp(cs, J, com, AllocationParams.checked("test", tau_max=tmax))
    solver = make_solver("daqp")
    assert solve_allocation(qp, solver, screening=True).rounds > 1  # rows bind in every case
    late = solve_allocation(qp, solver, screening=True, deadline_ns=0)  # always passed
    assert late.status == "deadline" and late.x is None and late.rounds == 0
    allocator = QPAllocator(tau_max=tmax, options=SolveOptions(warm_start=False, deadline=1e-9))
    allocation = allocator.allocate(cs, J, com)
    assert allocation.status == AllocationStatus.DEADLINE and allocation.tau is None
    assert allocator.counts[AllocationStatus.DEADLINE] == 1
    # Without a deadline the same allocator is exact (the deadline changes nothing else).
    exact = QPAllocator(tau_max=tmax, options=SolveOptions(warm_start=False)).allocate(cs, J, com)
    assert exact.fresh


class _Clock:
    """``time.perf_counter_ns`` that only the solver moves: each solve takes ``solve_ns``."""

    def __init__(self, solve_ns: int) -> None:
        self.now, self.solve_ns = 0, solve_ns

    def perf_counter_ns(self) -> int:
        return self.now


class _TimedSolve:
    """DAQP whose every solve takes ``clock.solve_ns`` on ``clock``."""

    def __init__(self, clock: _Clock) -> None:
        self.inner, self.clock, self.calls = make_solver("daqp"), clock, 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def solve(self, qp: Any, x0: Any = None, warm: bool = False, time_limit: Any = None) -> Any:
        self.calls += 1
        self.clock.now += self.clock.solve_ns
        return self.inner.solve(qp, x0, warm, None)


@pytest.mark.parametrize("case", CASES)
def test_no_round_is_built_once_the_deadline_has_passed(
    case: tuple[int, int, float], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A round finishing at or past the deadline ends the allocation there, without building the
    next round's problem; one nanosecond left starts the next round."""
    n, seed, tmax = case
    cs, J, com = synthetic_grasp(seed, n).cycle()
    qp = build_allocation_qp(cs, J, com, AllocationParams.checked("test", tau_max=tmax))
    clock = _Clock(solve_ns=1000)
    monkeypatch.setattr(solve_module, "time", clock)
    built = []
    round_problem = solve_module._round_problem
    monkeypatch.setattr(
        solve_module, "_round_problem", lambda *a: built.append(1) or round_problem(*a)
    )
    free = solve_allocation(qp, _TimedSolve(clock), screening=True)
    assert free.rounds > 1  # rows bind in every case
    for budget, rounds in ((1000, 1), (1001, 2)):  # each solve takes 1000 ns
        clock.now, built = 0, []
        solver = _TimedSolve(clock)
        sol = solve_allocation(qp, solver, screening=True, deadline_ns=budget)
        assert solver.calls == len(built) == sol.rounds == rounds
        assert sol.status == ("deadline" if rounds < free.rounds else "optimal")


def near_loss() -> tuple[ContactSet, np.ndarray, np.ndarray]:
    """A recorded hard cycle: the mustard bottle's grasp 0 pulled by 90 deg, 42 contacts just
    before the loss (``wholehand bench cycle --worst``). The wrench cannot be balanced, most
    edge weights are zero at the optimum, and torque and consistency rows bind: a cold DAQP
    solve of the full problem takes hundreds of iterations."""
    d = np.load(Path(__file__).parent / "data" / "near_loss_allocation.npz")
    n = d["n_world"] / np.linalg.norm(d["n_world"], axis=1, keepdims=True)  # unit to 1e-7 there
    cs = contact_set(d["p_world"], n, d["link"], d["link_actuated"], d["link_fingertip"])
    return cs, d["J_world"], d["p_com_world"]


def test_the_recorded_near_loss_cycle_is_solved_exactly() -> None:
    cs, J, com = near_loss()
    params = AllocationParams.checked("test")
    alloc = QPAllocator().allocate(cs, J, com)
    check_allocation(alloc, cs, J, com, params)
    qp = build_allocation_qp(cs, J, com, params)
    best, _ = reference(qp)  # the full problem, certified by its KKT residuals
    w = alloc.residual_wrench
    assert 0.5 * float(w @ w) == pytest.approx(best, rel=1e-5)  # best has the tiny ridge too
    assert np.linalg.norm(w) > 1.0  # not balanced: the grasp is being lost


@pytest.mark.parametrize("solver", ["daqp", "osqp"])
def test_a_solver_stops_itself_at_its_time_limit(solver: str) -> None:
    """A limit far below one solve stops the solver itself (status deadline, no x); a generous
    one changes nothing."""
    cs, J, com = near_loss()
    qp = build_allocation_qp(cs, J, com, AllocationParams.checked("test"))
    rows = np.arange(qp.torque_rows.size), np.arange(qp.n_null)
    adapter = make_solver(solver)
    assert adapter.time_limited
    free = adapter.solve(dense_qp(qp, *rows))
    assert free.status == "optimal" and free.iterations > 64  # longer than one clock check
    stopped = adapter.solve(dense_qp(qp, *rows), time_limit=1e-9)
    assert stopped.status == "deadline" and stopped.x is None
    roomy = adapter.solve(dense_qp(qp, *rows), time_limit=60.0)
    assert roomy.status == "optimal" and roomy.x is not None and free.x is not None
    np.testing.assert_allclose(roomy.x, free.x, atol=1e-6)


def test_daqp_keeps_one_model_per_shape_and_notices_a_new_hessian_or_limit() -> None:
    """The adapter reuses a problem shape's model: a Hessian diagonal of that shape with other
    values (a new array, or the same array changed in place) sets it up again, and a time limit
    lifted again after a stopped solve lets the next solve finish. Checked against the
    closed-form optimum of ``min 1/2 sum p_i x_i^2 s.t. x_1 + x_2 >= 1``: ``x_i = (1/p_i) /
    sum(1/p)``."""
    adapter = make_solver("daqp")

    def problem(p: np.ndarray) -> DenseQP:
        return DenseQP(
            p,
            np.array([[1.0, 1.0]]),
            np.ones(1),
            np.full(1, np.inf),
            0,
            np.full(2, -np.inf),
            np.full(2, np.inf),
        )

    def optimum(p: np.ndarray) -> np.ndarray:
        return (1.0 / p) / (1.0 / p).sum()

    p = np.array([1.0, 3.0])
    for _ in range(2):  # the second solve reuses the model
        np.testing.assert_allclose(adapter.solve(problem(p)).x, optimum(p), atol=1e-12)
    p[:] = [2.0, 1.0]  # the same array, changed in place
    np.testing.assert_allclose(adapter.solve(problem(p)).x, optimum(p), atol=1e-12)
    fixed = np.array([4.0, 1.0])
    fixed.setflags(write=False)
    np.testing.assert_allclose(adapter.solve(problem(fixed)).x, optimum(fixed), atol=1e-12)
    np.testing.assert_allclose(adapter.solve(problem(fixed)).x, optimum(fixed), atol=1e-12)
    cs, J, com = near_loss()
    qp = build_allocation_qp(cs, J, com, AllocationParams.checked("test"))
    rows = np.arange(qp.torque_rows.size), np.arange(qp.n_null)
    assert adapter.solve(dense_qp(qp, *rows), time_limit=1e-9).status == "deadline"
    assert adapter.solve(dense_qp(qp, *rows)).status == "optimal"  # no limit left behind


def test_deadline_must_be_positive() -> None:
    with pytest.raises(ConfigError, match="deadline=0"):
        QPAllocator(options=SolveOptions(deadline=0))


@pytest.mark.parametrize("solver", ["daqp", "osqp"])
def test_loading_the_kernels_solves_a_problem_with_every_row_kind(solver: str, allegro) -> None:
    params = AllocationParams.checked("test", **hand_keywords(allegro))
    sol = load_kernels(params, make_solver(solver))
    assert sol.status == "optimal" and sol.violation < 1e-6
    assert sol.torque_sel.size > 0 and sol.null_sel.size == 1  # torque and consistency rows


@pytest.mark.parametrize("case", CASES[:3])
def test_the_paper_labs_form_has_the_allocations_optimum(case: tuple[int, int, float]) -> None:
    """The baseline of `bench allocate`: forces and the wrench as variables, the wrench as
    equality rows, solved by OSQP, reaches the residual wrench of the allocator's optimum, up to
    what the two ridges may move it: reg/2 of the squared norms of the two solutions (on the
    forces there, on the edge weights here)."""
    from wholehand.allocation.reference import paper_lab_problem

    n, seed, tmax = case
    cs, J, com = synthetic_grasp(seed, n).cycle()
    qp = build_allocation_qp(cs, J, com, AllocationParams.checked("test", tau_max=tmax))
    problem = paper_lab_problem(qp)
    sol = qpsolvers.solve_problem(problem, solver="osqp", **settings_for("osqp"))
    assert sol.found
    f, w = sol.x[: 3 * qp.n_contacts], sol.x[3 * qp.n_contacts :]
    np.testing.assert_allclose(w, qp.G @ f + qp.w_ext, atol=1e-6)
    best, ref = reference(qp)
    lam = ref.x[: qp.n_lambda]
    ridges = 0.5 * qp.params.reg * float(f @ f + lam @ lam)
    assert 0.5 * float(w @ w) == pytest.approx(best, abs=ridges + 1e-7)
