"""The batched synthesis against one-at-a-time ground truth: kinematics against Pinocchio's per
configuration, generalised forces against per-point Jacobians, the cull against the nearest-node
lookup, the fingers' close pairs against a k-d tree per start, a batch's energies against each
start's alone."""

from __future__ import annotations

from dataclasses import astuple

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from wholehand.grasps.synthesis import GraspSynthesizer, SynthesisState
from wholehand.grasps.synthesis_params import SynthesisParams
from wholehand.models.batch_kinematics import BatchKinematics
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel
from wholehand.models.sdf import SignedDistanceGrid


@pytest.fixture(scope="module")
def ball() -> ObjectModel:
    return ObjectModel.sphere(0.035, mass=0.1, sdf_spacing=0.002)


@pytest.fixture(scope="module")
def coupled(tmp_path_factory):
    from toy_hand import write_toy_hand

    from wholehand.models.hand import load_hand

    return load_hand(write_toy_hand(tmp_path_factory.mktemp("toy"), mimic=True))


def _poses(rng: np.random.Generator, n: int) -> np.ndarray:
    oMb = np.repeat(np.eye(4)[None], n, axis=0)
    oMb[:, :3, :3] = Rotation.random(n, random_state=rng.integers(2**31)).as_matrix()
    oMb[:, :3, 3] = rng.uniform(-0.1, 0.1, size=(n, 3))
    return oMb


@pytest.mark.parametrize("which", ["allegro", "coupled"])
def test_batch_kinematics_are_pinocchios_configuration_by_configuration(which, request):
    hand = request.getfixturevalue(which)
    rng = np.random.default_rng(4)
    q = np.stack([hand.couple(rng.uniform(hand.q_lower, hand.q_upper)) for _ in range(5)])
    oMb = _poses(rng, 5)
    batch = BatchKinematics(hand)
    batch.update(q, oMb)
    s = hand.samples
    X = batch.transform(s.p_joint, s.joint)
    pick = rng.choice(s.joint.size, size=40, replace=False)
    forces = rng.normal(size=(5, 40, 3))
    moments = rng.normal(size=(5, 40, 3))
    force, moment, tau = batch.generalized_forces(
        np.repeat(np.arange(5), 40),
        np.tile(s.joint[pick], 5),
        X[:, pick].reshape(-1, 3),
        forces.reshape(-1, 3),
        moments.reshape(-1, 3),
    )
    one = HandKinematics(hand)
    for b in range(5):
        one.update(q[b], oMb[b])
        p = one.transform_points(s.p_joint, s.joint)
        np.testing.assert_allclose(X[b], p, atol=1e-14)
        J = one.point_jacobians(s.joint[pick], p[pick])
        Jw = one.angular_jacobians(s.joint[pick])
        expected = np.einsum("nak,na->k", J, forces[b]) + np.einsum("nak,na->k", Jw, moments[b])
        np.testing.assert_allclose(tau[b], expected, atol=1e-12)
        np.testing.assert_allclose(force[b], forces[b].sum(axis=0), atol=1e-12)
        lever = p[pick] - oMb[b, :3, 3]
        about = np.cross(lever, forces[b]).sum(axis=0) + moments[b].sum(axis=0)
        np.testing.assert_allclose(moment[b], about, atol=1e-12)


def test_nearest_below_is_the_nearest_node_cull(ball):
    """Inside, outside and far beyond the grid box, and NaN (never below)."""
    rng = np.random.default_rng(0)
    points = rng.normal(scale=0.05, size=(20000, 3))
    points[:50] *= 10.0  # far outside the box
    points[50:55] = np.nan
    for threshold in (-0.01, 0.0, 0.002, 0.05, 1.0):
        expected = np.flatnonzero(ball.sdf.query_nearest(points) < threshold)
        np.testing.assert_array_equal(ball.sdf.nearest_below(points, threshold), expected)


@pytest.mark.parametrize("shape", ["ball", "box"])
def test_near_spheres_drops_only_balls_with_no_point_below_the_threshold(ball, shape):
    """Balls about random centres in, near and beyond the grid box, with points filling each
    (its boundary too): a ball said to be out of reach has no point whose nearest-node value
    is below the threshold, and most far balls are said to be out of reach."""
    obj = ball if shape == "ball" else ObjectModel.box((0.06, 0.03, 0.09), mass=0.1)
    sdf = obj.sdf
    rng = np.random.default_rng(6)
    lo, hi = sdf.bounds
    centres = rng.uniform(lo - 0.03, hi + 0.03, size=(3000, 3))
    radius = rng.uniform(0.0, 0.02, size=3000)
    directions = rng.normal(size=(3000, 64, 3))
    directions /= np.linalg.norm(directions, axis=2, keepdims=True)
    reach = radius[:, None] * np.concatenate((np.ones((3000, 8)), rng.random((3000, 56))), axis=1)
    points = centres[:, None] + directions * reach[..., None]
    for threshold in (0.0, sdf.spacing, 0.01):
        near = sdf.near_spheres(centres, radius, threshold)
        below = (sdf.query_nearest(points.reshape(-1, 3)) < threshold).reshape(3000, 64)
        assert not (below.any(axis=1) & ~near).any()
        assert (~near).sum() > 0.5 * (~below.any(axis=1)).sum()
    assert sdf.near_spheres(centres, radius, -0.001).all()  # no bound below zero


@pytest.mark.parametrize("table", [None, [0.0, 0.0, 1.0]])
def test_the_culled_energies_are_those_of_every_sample(allegro, ball, table, monkeypatch):
    """Hands pushed into the ball and onto the table: the numpy form's energies and gradients
    with the cluster cull equal those computed over every hand sample (the compiled form's
    cull: tests/test_synthesis_kernel.py)."""
    syn = GraspSynthesizer(allegro, ball, allegro.config.grasp_styles["power"], table_up=table)
    syn.compiled = False
    rng = np.random.default_rng(8)
    starts = [syn.start(rng) for _ in range(12)]
    oMb = np.stack([st.oMb for st in starts])
    oMb[:, :3, 3] -= 0.004 * np.arange(12)[:, None] * oMb[:, :3, 0]
    a = np.stack([rng.uniform(syn.a_lower, syn.a_upper) for _ in starts])
    contacts = np.stack([st.contacts for st in starts])
    culled, culled_grad = syn.energies(oMb, a, contacts)
    assert (culled.penetration > 0).sum() >= 6
    if table is not None:
        assert (culled.table > 0).sum() >= 6
    monkeypatch.setattr(
        SignedDistanceGrid, "near_spheres", lambda self, c, r, t: np.ones(len(c), dtype=bool)
    )
    every, every_grad = syn.energies(oMb, a, contacts)
    np.testing.assert_array_equal(culled.max_depth, every.max_depth)
    for name in ("total", "penetration", "table"):
        np.testing.assert_allclose(getattr(culled, name), getattr(every, name), rtol=1e-13)
    for key in ("t", "w", "a"):
        np.testing.assert_allclose(culled_grad[key], every_grad[key], rtol=1e-12, atol=1e-13)


def test_the_fingers_close_pairs_are_every_pair_within_the_gap(allegro, ball):
    """Hands pressed into fists at random: the pairs of two fingers' samples within the gap
    are those a k-d tree over each start's samples finds."""
    params = SynthesisParams(self_gap=0.01)
    syn = GraspSynthesizer(allegro, ball, allegro.config.grasp_styles["power"], params=params)
    rng = np.random.default_rng(1)
    n = 8
    a = rng.uniform(syn.a_lower, syn.a_upper, size=(n, syn.a_lower.size))
    syn.batch_kin.update(syn.q_of(a), _poses(rng, n))
    rows, finger = syn.self_samples, syn.self_finger
    X = syn.batch_kin.transform(syn.samples.p_joint[rows], syn.samples.joint[rows])
    start, i, j, dist = syn._self_pairs(X)
    found = {(int(b), *sorted((int(x), int(y)))) for b, x, y in zip(start, i, j, strict=True)}
    expected = set()
    for b in range(n):
        for x, y in cKDTree(X[b]).query_pairs(params.self_gap):
            if finger[x] != finger[y]:
                expected.add((b, *sorted((int(x), int(y)))))
    assert expected and found == expected
    np.testing.assert_allclose(dist, np.linalg.norm(X[start, i] - X[start, j], axis=1))


@pytest.mark.parametrize("table", [None, [0.0, 0.0, 1.0]])
def test_a_batchs_energies_and_gradients_are_each_starts_alone(allegro, ball, table):
    params = SynthesisParams(self_gap=0.015)  # wide: random joint angles touch fingers
    syn = GraspSynthesizer(
        allegro, ball, allegro.config.grasp_styles["power"], table_up=table, params=params
    )
    rng = np.random.default_rng(2)
    starts = [syn.start(rng) for _ in range(6)]
    for k, st in enumerate(starts):  # some into the ball, some fingers together
        st.oMb[:3, 3] -= 0.01 * k * st.oMb[:3, 0]
        st.a = rng.uniform(syn.a_lower, syn.a_upper)
    energies, grad = syn.energies(
        np.stack([st.oMb for st in starts]),
        np.stack([st.a for st in starts]),
        np.stack([st.contacts for st in starts]),
    )
    assert (energies.penetration > 0).any() and (energies.self_penetration > 0).any()
    for b, st in enumerate(starts):
        alone = SynthesisState(st.oMb, st.a, st.contacts)
        energy = syn.evaluate(alone)
        assert astuple(energies.at(b)) == pytest.approx(astuple(energy), rel=1e-12, abs=1e-15)
        for key in ("t", "w", "a"):
            np.testing.assert_allclose(grad[key][b], alone.grad[key], rtol=1e-10, atol=1e-12)


def test_a_copied_batch_kinematics_reads_its_own_pinocchio_data(allegro):
    """A deep copy (as a study's worker gets) views its own Pinocchio data: updating it gives
    the original's placements, and updating the original afterwards leaves the copy as it was."""
    import copy

    rng = np.random.default_rng(5)
    q = rng.uniform(allegro.q_lower, allegro.q_upper, size=(2, allegro.nq))
    oMb = _poses(rng, 2)
    batch = BatchKinematics(allegro)
    twin = copy.deepcopy(batch)
    batch.update(q, oMb)
    twin.update(q, oMb)
    np.testing.assert_array_equal(twin.R, batch.R)
    batch.update(q[::-1], oMb[::-1])
    assert not np.array_equal(twin.R, batch.R)
