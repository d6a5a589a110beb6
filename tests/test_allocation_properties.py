"""Property test of the allocator over random contact sets (hypothesis, derandomised): it never
raises, its torque stays within the limits, and its status agrees with its residual."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from wholehand_plugins.qp import QPAllocator

from wholehand.allocation.base import AllocationStatus, is_balanced
from wholehand.contacts.base import ContactSet

NO_TORQUE = {
    AllocationStatus.INFEASIBLE,
    AllocationStatus.SOLVER_FAILED,
    AllocationStatus.INACCURATE,
}


@st.composite
def problems(draw: st.DrawFn) -> tuple[ContactSet, np.ndarray, np.ndarray, dict[str, float]]:
    seed = draw(st.integers(0, 2**31 - 1))
    n = draw(st.integers(0, 24))
    n_v = draw(st.integers(1, 8))
    n_links = draw(st.integers(1, 6))
    rng = np.random.default_rng(seed)
    normals = rng.standard_normal((n, 3))
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    link_actuated = rng.random(n_links) < 0.8
    contacts = ContactSet(
        p_world=rng.normal(scale=0.05, size=(n, 3)),
        n_world=normals,
        link=rng.integers(0, n_links, n).astype(np.intp),
        distance=np.zeros(n),
        link_actuated=link_actuated,
        link_fingertip=rng.random(n_links) < 0.5,
    )
    scale = draw(st.sampled_from([1e-3, 1e-2, 0.05, 0.3]))
    J = rng.normal(scale=scale, size=(n, 3, n_v))
    if n and draw(st.booleans()) and draw(st.booleans()):
        J[rng.integers(n), rng.integers(3), rng.integers(n_v)] = np.nan
    params = {
        "tau_max": draw(st.sampled_from([1e-3, 0.05, 0.2, 1.0])),
        "f_n_min": draw(st.sampled_from([0.0, 1.0, 10.0, 1e3])),
        "mu": draw(st.sampled_from([0.0, 0.3, 0.7, 1.5])),
    }
    return contacts, J, rng.normal(scale=0.02, size=3), params


@settings(
    max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)
@given(problems())
def test_the_allocator_never_raises_respects_limits_and_reports_its_residual(problem) -> None:
    contacts, J, com, params = problem
    alloc = QPAllocator(**params)
    out = alloc.allocate(contacts, J, com)
    n, n_v = len(contacts), J.shape[2]
    assert out.f_world.shape == out.f_local.shape == (n, 3)
    assert (out.tau is None) == (out.status in NO_TORQUE)
    if out.tau is not None:
        assert out.tau.shape == (n_v,)
        assert np.all(
            np.abs(out.tau) <= np.asarray(params["tau_max"]) * (1.0 + alloc.options.feas_tol)
        )
    if out.fresh:
        assert (out.status is AllocationStatus.OK) == out.balanced
        # The residual is the net wrench of the forces about the centre of mass (hand-computed).
        f = out.f_world
        wrench = np.r_[f.sum(axis=0), np.cross(contacts.p_world - com, f).sum(axis=0)]
        np.testing.assert_allclose(out.residual_wrench, wrench, atol=1e-6)
        # Forces push on the object and lie in the friction pyramid of their contact.
        fn, t1, t2 = out.f_local.T
        assert np.all(fn >= -1e-6)
        assert np.all(np.abs(t1) <= params["mu"] * fn + 1e-6)
        assert np.all(np.abs(t2) <= params["mu"] * fn + 1e-6)
        np.testing.assert_allclose(np.einsum("ij,ij->i", f, contacts.n_world), -fn, atol=1e-6)
        assert fn.sum() >= params["f_n_min"] - 1e-4
    assert out.balanced == is_balanced(out.residual_wrench, out.f_world)
    if out.status in (AllocationStatus.EMPTY, AllocationStatus.NO_ACTUATED_CONTACT):
        assert not out.tau.any() and not out.balanced
