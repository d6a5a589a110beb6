"""Loading the allocation's compiled kernels at an allocator's construction, before any cycle."""

from __future__ import annotations

import dataclasses

import numpy as np

from wholehand.allocation.kernels import finite_inputs
from wholehand.allocation.problem import AllocationParams, build_allocation_qp
from wholehand.allocation.screening_kernels import priced_edges
from wholehand.allocation.solution import ActiveSet, AllocationSolution
from wholehand.allocation.solve import binding_rows, dense_qp, solve_allocation
from wholehand.allocation.solvers import QPSolver
from wholehand.allocation.warm_start import matched_contacts, rows_of_joints, warm_edge_weights
from wholehand.contacts.base import ContactSet


def load_kernels(
    params: AllocationParams, solver: QPSolver, dual_active_set: bool = False
) -> AllocationSolution:
    """Run every compiled kernel of building and solving the allocation QP once, then forget
    the solver's state; returns the solution of the synthetic problem it solved. With
    ``dual_active_set`` the dual active-set solver's kernel too.

    A kernel's first call in a process loads its machine code (tens of milliseconds for all of
    them, seconds when it is compiled); allocators call this at construction so that this
    never falls in a control cycle. The problem has the parameters' joints and, so that it is
    solved with torque and consistency rows in it, loose limits: more contact rows than joints,
    every torque row and one consistency row from the start.
    """
    n_v = 2
    if params.actuated_dofs is not None and params.actuated_dofs.size:
        n_v = int(params.actuated_dofs[-1]) + 1
    if np.ndim(params.tau_max) == 1:
        n_v = np.shape(params.tau_max)[0]
    loose = dataclasses.replace(
        params,
        tau_max=np.full(n_v, 1e3) if np.ndim(params.tau_max) == 1 else 1e3,
        eps_margin=1e3,
    )
    n = n_v // 3 + 2  # 3 n rows > n_v joints: the rows of J_act^T have a null space
    rng = np.random.default_rng(0)
    normals = rng.normal(size=(n, 3))
    contacts = ContactSet(
        p_world=rng.normal(scale=0.05, size=(n, 3)),
        n_world=normals / np.linalg.norm(normals, axis=1, keepdims=True),
        link=np.zeros(n, dtype=np.intp),
        distance=np.zeros(n),
        link_actuated=np.ones(1, dtype=bool),
        link_fingertip=np.zeros(1, dtype=bool),
    )
    J = rng.normal(scale=0.05, size=(n, 3, n_v))
    finite_inputs(contacts.p_world, contacts.n_world, J, np.zeros(3))
    qp = build_allocation_qp(contacts, J, np.zeros(3), loose, "load_kernels")
    every_t = np.arange(qp.torque_rows.size, dtype=np.intp)
    some_n = np.arange(min(qp.n_null, 1), dtype=np.intp)
    sol = solve_allocation(qp, solver, torque_sel=every_t, null_sel=some_n)
    if sol.x is not None:
        lam = sol.x[: qp.n_lambda]
        qp.tau(lam), qp.f_world(lam), binding_rows(qp, sol)
    # A round of edge screening: its active set, and a solve that starts from one.
    n_duals = qp.n_x + 7 + every_t.size + some_n.size
    guess = ActiveSet.of(qp, np.zeros(n_duals), every_t, some_n, None)
    solver.solve(dense_qp(qp, every_t, some_n, np.arange(qp.n_lambda, dtype=np.intp), guess))
    rows_of_joints(qp.dofs[qp.torque_rows], qp.n_v, qp.dofs, qp.torque_rows)  # the warm start's
    p, link = contacts.p_world, contacts.link  # the warm start's contact match
    warm_edge_weights(matched_contacts(p, link, p.copy(), link.copy(), 1e-6), np.ones((n, 4)))
    y = np.zeros(7 + every_t.size + some_n.size)  # the pricing of edge screening's rounds
    priced_edges(
        qp.G_lam, qp.T_lam, every_t, qp.null_rows(some_n), y, np.zeros(qp.n_lambda, bool), 0.0
    )
    if dual_active_set:
        from wholehand.allocation.solvers.dual_active_set import solve_dual_active_set

        solve_dual_active_set(qp)
    solver.reset()
    return sol


__all__ = ["load_kernels"]
