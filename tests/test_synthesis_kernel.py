"""The compiled synthesis energy against its numpy form, and its point lookups against the
grid's own: the same energies, gradients and contact terms on batches that press hands into
the object, onto the table and fingers into each other, on a plain and a coupled hand."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

from wholehand.grasps.synthesis import GraspSynthesizer
from wholehand.grasps.synthesis_kernel import batch_energy
from wholehand.grasps.synthesis_params import SynthesisParams
from wholehand.models.objects import ObjectModel
from wholehand.models.sdf_lookup import (
    grid_arguments,
    grid_tuples,
    nearest_node_value,
)


@pytest.fixture(scope="module")
def ball() -> ObjectModel:
    return ObjectModel.sphere(0.035, mass=0.1, sdf_spacing=0.002)


@pytest.fixture(scope="module")
def box() -> ObjectModel:
    return ObjectModel.box((0.06, 0.03, 0.09), mass=0.1)


@pytest.fixture(scope="module")
def coupled(tmp_path_factory):
    from toy_hand import write_toy_hand

    from wholehand.models.hand import load_hand

    return load_hand(write_toy_hand(tmp_path_factory.mktemp("toy"), mimic=True))


def _pressed_batch(syn: GraspSynthesizer, n: int, seed: int):
    """Seeded starts moved 0-6 cm toward the object along their palm normals, joints anywhere
    in their range: some into the object, some on the table, some fingers together."""
    rng = np.random.default_rng(seed)
    starts = [syn.start(rng) for _ in range(n)]
    oMb = np.stack([st.oMb for st in starts])
    toward = oMb[:, :3, :3] @ syn.palm.bRp[:, 0]
    oMb[:, :3, 3] += 0.004 * np.arange(n)[:, None] * toward
    a = np.stack([rng.uniform(syn.a_lower, syn.a_upper) for _ in starts])
    contacts = np.stack([st.contacts for st in starts])
    return oMb, a, contacts


def _both(syn: GraspSynthesizer, batch):
    syn.compiled = True
    compiled = syn.energies(*batch)
    syn.compiled = False
    reference = syn.energies(*batch)
    syn.compiled = True
    return compiled, reference


@pytest.mark.parametrize(
    ("hand", "obj", "table"),
    [
        ("allegro", "ball", None),
        ("allegro", "box", [0.0, 0.0, 1.0]),
        ("coupled", "ball", [0.0, 1.0, 0.0]),
    ],
)
def test_the_compiled_energy_is_the_numpy_forms(hand, obj, table, request):
    hand, obj = request.getfixturevalue(hand), request.getfixturevalue(obj)
    params = SynthesisParams(self_gap=0.015)  # wide: random joint angles touch fingers
    syn = GraspSynthesizer(
        hand, obj, hand.config.grasp_styles["power"], table_up=table, params=params
    )
    batch = _pressed_batch(syn, 16, seed=3)
    (energies, grad), (expected, expected_grad) = _both(syn, batch)
    assert (expected.penetration > 0).sum() >= 4
    if table is not None:
        assert (expected.table > 0).sum() >= 4
    if hand.name != "toy":
        assert (expected.self_penetration > 0).sum() >= 2
    for f in fields(expected):
        np.testing.assert_allclose(
            getattr(energies, f.name), getattr(expected, f.name), rtol=1e-12, atol=1e-15
        )
    for key in ("t", "w", "a"):
        scale = np.abs(expected_grad[key]).max()
        np.testing.assert_allclose(grad[key], expected_grad[key], rtol=0, atol=1e-12 * scale)
    _, dc, gc = syn.contact_terms(*batch)
    syn.batch_kin.update(syn.q_of(batch[1]), batch[0])
    s = syn.samples
    xc = syn.batch_kin.transform_each(s.p_joint, s.joint, batch[2])
    d_ref, g_ref = obj.sdf.query_with_gradient(xc.reshape(-1, 3))
    np.testing.assert_array_equal(dc.reshape(-1), d_ref)
    np.testing.assert_array_equal(gc.reshape(-1, 3), g_ref)


@pytest.mark.parametrize("table", [None, [0.0, 0.0, 1.0]])
def test_the_compiled_cull_keeps_every_sample_that_counts(allegro, ball, table):
    """The kernel with its cluster cull and with every cluster looked at: equal energies and
    gradients on hands pushed into the ball and onto the table."""
    syn = GraspSynthesizer(allegro, ball, allegro.config.grasp_styles["power"], table_up=table)
    batch = _pressed_batch(syn, 12, seed=8)
    syn.energies(*batch)
    scene, points = syn._kernel_inputs()
    assert scene.cull
    kin = syn.batch_kin
    args = (kin.R, kin.t, kin.v, kin.w, np.ascontiguousarray(batch[0][:, :3, 3]), kin.support)
    culled = batch_energy(scene, points, args, batch[2], True)
    every = batch_energy(scene._replace(cull=False), points, args, batch[2], True)
    assert (culled[0][:, 4] > 0).sum() >= 6
    np.testing.assert_array_equal(culled[0][:, 6], every[0][:, 6])  # the deepest sample
    for k in range(1, 4):  # force, moment, generalised forces
        np.testing.assert_allclose(culled[k], every[k], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(culled[0], every[0], rtol=1e-13)


@pytest.mark.parametrize("obj", ["ball", "box"])
def test_the_nearest_node_lookup_is_the_grids(obj, request):
    """The nearest node's value plus the distance outside the box, point by point, against the
    grid's vectorised ``query_nearest``: in, near and beyond the box, and NaN. (The ball bound
    built on it is ``near_spheres``, tested against filled balls in test_batch_synthesis.py.)"""
    sdf = request.getfixturevalue(obj).sdf
    values, dims, geom = grid_arguments(sdf)
    shape, g = grid_tuples(dims, geom)
    rng = np.random.default_rng(2)
    lo, hi = sdf.bounds
    points = rng.uniform(lo - 0.05, hi + 0.05, size=(4000, 3))
    points[:3] = np.nan
    nearest = np.array([sum(nearest_node_value(values, shape, g, *p)) for p in points])
    np.testing.assert_allclose(nearest, sdf.query_nearest(points), rtol=0, atol=1e-12)
    assert np.isnan(nearest[:3]).all()
