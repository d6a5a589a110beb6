"""The numba contact kernels against a straightforward numpy reference.

The reference moves every hand sample to the object frame (``HandKinematics.transform_points``),
looks it up with ``SignedDistanceGrid.query``, thresholds, keeps the top K per link
(``top_k_per_link``) and takes normals from ``SignedDistanceGrid.query_with_gradient``: no
culling, no kernel. States are seeded random hand configurations, base poses and object poses.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
from wholehand_plugins.mesh_sdf import MeshSDFEstimator, kernels
from wholehand_plugins.mesh_sdf.reference import sdf_query, top_k_per_link

from wholehand.bench.contacts import grasp_like_states
from wholehand.errors import ConfigError
from wholehand.grasps.store import load_grasps
from wholehand.models import sdf_lookup
from wholehand.models.kinematics import HandKinematics
from wholehand.models.object_catalogue import load_object
from wholehand.models.objects import ObjectModel
from wholehand.models.poses import inverse, pose_from_xyz_rpy
from wholehand.models.sdf import SignedDistanceGrid

N_STATES = 12
ATOL = 1e-9  # distances [m] and normals: the kernel repeats the grid's float32 arithmetic


@pytest.fixture(scope="module")
def cube():
    return load_object("077_rubiks_cube")


@pytest.fixture(scope="module")
def sphere():
    return ObjectModel.sphere(0.04, mass=0.2)


@pytest.fixture(scope="module")
def tight_sphere():
    """A sphere whose grid ends 12 mm past the surface: hand samples near the object fall
    outside the grid box and take the outside rule (d_thresh = 1 cm still fits the grid)."""
    return ObjectModel.sphere(0.04, mass=0.2, sdf_padding=0.012)


def reference(hand, obj, kin, wMo, d_thresh, k, links=None):
    """(p_world, n_world, link, distance) by brute force, ordered by link then distance."""
    s = hand.samples
    rows = np.arange(len(s))
    if links is not None:
        rows = np.flatnonzero(np.isin(s.link, [hand.link_index(name) for name in links]))
    p_obj = kin.transform_points(s.p_joint[rows], s.joint[rows], inverse(wMo))
    d = obj.sdf.query(p_obj)
    close = np.flatnonzero(d < d_thresh)
    keep = close[top_k_per_link(s.link[rows][close], d[close], k)]
    d_kept, grad = obj.sdf.query_with_gradient(p_obj[keep])
    wRo = wMo[:3, :3]
    return p_obj[keep] @ wRo.T + wMo[:3, 3], grad @ wRo.T, s.link[rows][keep], d_kept


@numba.njit
def kernel_values(values, dims, geom, points):
    """(P,) ``sdf_lookup.sdf_value`` (the lookup of the cull and the threshold) at (P, 3) points."""
    shape = (dims[0], dims[1], dims[2])
    g = (geom[0], geom[1], geom[2], geom[3], geom[4])
    out = np.empty(points.shape[0])
    for i in range(points.shape[0]):
        out[i] = sdf_lookup.sdf_value(values, shape, g, points[i, 0], points[i, 1], points[i, 2])
    return out


def canonical(p, n, link, d):
    """Rows ordered by link, distance, then position: equal distances within a link (possible
    with float32 grid values) may come in either order."""
    order = np.lexsort((p[:, 2], p[:, 1], p[:, 0], d, link))
    return p[order], n[order], link[order], d[order]


def random_states(hand, obj, seed, count=N_STATES):
    """Seeded (q, wMb, wMo) triples: grasp-like states (object against the palm, fingers half
    closed) moved by one random rigid motion each, plus random joint offsets."""
    rng = np.random.default_rng(seed)
    qs, poses = grasp_like_states(hand, obj, count, seed)
    for q, wMo in zip(qs, poses, strict=True):
        T = pose_from_xyz_rpy(rng.uniform(-0.5, 0.5, 3), rng.uniform(-np.pi, np.pi, 3))
        q = np.clip(q + rng.normal(0.0, 0.1, q.shape), hand.q_lower, hand.q_upper)
        yield q, T @ hand.wMb, T @ wMo


def assert_matches_reference(hand, obj, contacts, kin, wMo, d_thresh, k, links=None):
    want = reference(hand, obj, kin, wMo, d_thresh, k, links)
    # Ordered by link then distance, exactly as the reference.
    np.testing.assert_array_equal(contacts.link, want[2])
    np.testing.assert_allclose(contacts.distance, want[3], rtol=0, atol=ATOL)
    got = canonical(contacts.p_world, contacts.n_world, contacts.link, contacts.distance)
    want = canonical(*want)
    np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[1], want[1], rtol=0, atol=ATOL)
    assert contacts.p_world.dtype == np.float64 and contacts.link.dtype == np.intp


@pytest.mark.parametrize("obj_name", ["cube", "sphere", "tight_sphere"])
@pytest.mark.parametrize("k", [1, 5, 7])
def test_estimator_equals_numpy_reference(allegro, request, obj_name, k):
    """The paper's selection (no hysteresis) against brute force, state after state."""
    obj = request.getfixturevalue(obj_name)
    est = MeshSDFEstimator(allegro, obj, d_thresh=0.01, k=k, hysteresis=0.0)
    kin = HandKinematics(allegro)
    total = 0
    for q, wMb, wMo in random_states(allegro, obj, seed=k):
        kin.update(q, wMb)
        contacts = est.estimate(kin, wMo, stamp=1.5)
        assert contacts.stamp == 1.5
        assert_matches_reference(allegro, obj, contacts, kin, wMo, 0.01, k)
        assert np.bincount(contacts.link).max(initial=0) <= k
        total += len(contacts)
    assert total > N_STATES  # the states do make contacts


def test_samples_outside_the_grid_are_looked_up(allegro, tight_sphere):
    """The tight grid case does exercise the outside rule: some samples of clusters that pass
    the cull lie outside the grid box, and the reference still agrees (test above)."""
    est = MeshSDFEstimator(allegro, tight_sphere, hysteresis=0.0)
    kin = HandKinematics(allegro)
    lo, hi = tight_sphere.sdf.bounds
    outside_near = 0
    for q, wMb, wMo in random_states(allegro, tight_sphere, seed=3):
        kin.update(q, wMb)
        s = allegro.samples
        p_obj = kin.transform_points(s.p_joint, s.joint, inverse(wMo))
        outside = np.any((p_obj < lo) | (p_obj > hi), axis=1)
        d = tight_sphere.sdf.query(p_obj)
        # Within a cluster's reach of a contact but outside the box: looked up by the kernel.
        outside_near += np.count_nonzero(outside & (d < est.d_thresh + 0.01))
        assert_matches_reference(allegro, tight_sphere, est.estimate(kin, wMo), kin, wMo, 0.01, 5)
    assert outside_near > 0


@pytest.mark.parametrize("k", [1, 7])
def test_links_filter_equals_reference(allegro, sphere, k):
    tips = [allegro.link_names[i] for i in np.flatnonzero(allegro.link_fingertip)]
    links = [*tips, allegro.palm_link]
    est = MeshSDFEstimator(allegro, sphere, d_thresh=0.015, k=k, links=links, hysteresis=0.0)
    kin = HandKinematics(allegro)
    allowed = {allegro.link_index(name) for name in links}
    for q, wMb, wMo in random_states(allegro, sphere, seed=10 + k):
        kin.update(q, wMb)
        contacts = est.estimate(kin, wMo)
        assert set(contacts.link.tolist()) <= allowed
        assert_matches_reference(allegro, sphere, contacts, kin, wMo, 0.015, k, links)


def test_far_object_gives_an_empty_set(allegro, cube):
    est = MeshSDFEstimator(allegro, cube)
    kin = HandKinematics(allegro)
    contacts = est.estimate(kin, pose_from_xyz_rpy([0.5, -0.3, 0.2], [0.1, 0.2, 0.3]), stamp=4.0)
    assert len(contacts) == 0 and contacts.stamp == 4.0
    assert contacts.p_world.shape == (0, 3) and contacts.n_world.shape == (0, 3)
    assert contacts.link.shape == (0,) and contacts.link.dtype == np.intp
    assert contacts.distance.shape == (0,)
    assert contacts.link_actuated.shape == (len(allegro.link_names),)


def test_results_are_fresh_arrays_and_layout_free(allegro, cube):
    """Each call returns new arrays (the kernel's scratch is never handed out), and a pose in
    Fortran order gives the same contacts as the same pose in C order."""
    est = MeshSDFEstimator(allegro, cube)
    kin = HandKinematics(allegro)
    states = list(random_states(allegro, cube, seed=21, count=2))
    kin.update(states[0][0], states[0][1])
    first = est.estimate(kin, states[0][2])
    kept = {name: np.copy(getattr(first, name)) for name in ("p_world", "n_world", "link")}
    again = est.estimate(kin, np.asfortranarray(states[0][2]))
    for name, value in kept.items():
        np.testing.assert_array_equal(getattr(again, name), value)
    kin.update(states[1][0], states[1][1])
    est.estimate(kin, states[1][2])
    for name, value in kept.items():
        np.testing.assert_array_equal(getattr(first, name), value)


def test_bad_inputs_raise(allegro, sphere):
    est = MeshSDFEstimator(allegro, sphere)
    kin = HandKinematics(allegro)
    bad = np.eye(4)
    bad[:3, :3] *= 2.0
    with pytest.raises(ConfigError, match="wMo.*rotation"):
        est.estimate(kin, bad)
    with pytest.raises(ConfigError, match="wMo.*shape"):
        est.estimate(kin, np.eye(3))
    kin.bRj = kin.bRj[:-1]  # kinematics of a hand with one joint less
    kin.bp_j = kin.bp_j[:-1]
    with pytest.raises(ConfigError, match="joints"):
        est.estimate(kin, np.eye(4))


@pytest.mark.parametrize("obj_name", ["cube", "tight_sphere"])
def test_lookups_equal_the_grid_bit_for_bit(request, obj_name):
    """sdf_query repeats SignedDistanceGrid.query_with_gradient exactly: inside, on nodes, on
    the box faces, outside the box, and NaN."""
    grid = request.getfixturevalue(obj_name).sdf
    lo, hi = grid.bounds
    rng = np.random.default_rng(7)
    span = hi - lo
    inside = rng.uniform(lo, hi, (2000, 3))
    around = rng.uniform(lo - 0.5 * span, hi + 0.5 * span, (2000, 3))
    nodes = grid.node_positions(rng.integers(0, grid.shape, (200, 3)))
    faces = rng.uniform(lo, hi, (300, 3))
    axis = rng.integers(0, 3, 300)
    faces[np.arange(300), axis] = np.where(rng.random(300) < 0.5, lo[axis], hi[axis])
    nan = inside[:3].copy()
    nan[np.arange(3), np.arange(3)] = np.nan
    points = np.concatenate([inside, around, nodes, faces, nan])
    args = sdf_lookup.grid_arguments(grid)
    d, g = sdf_query(*args, points)
    d_ref, g_ref = grid.query_with_gradient(points)
    np.testing.assert_array_equal(d, d_ref)
    np.testing.assert_array_equal(g, g_ref)
    np.testing.assert_array_equal(kernel_values(*args, points), grid.query(points))
    assert np.isnan(d[-3:]).all() and np.isnan(g[-3:]).all()


@pytest.mark.parametrize("k", [1, 3, 7])
def test_kernel_ties_keep_row_order(k):
    """On a constant grid every sample has the same distance: each link keeps its first k rows
    in row order, as the stable sort of ``top_k_per_link`` does."""
    grid = SignedDistanceGrid(origin=np.zeros(3), spacing=0.01, values=np.full((4, 4, 4), -0.001))
    rng = np.random.default_rng(k)
    link = np.repeat([0, 1, 3], [10, 12, 8])
    p_joint = rng.uniform(0.0, 0.03, (link.size, 3))
    cluster = np.arange(link.size) // 4  # clusters of 4 rows never straddle a link boundary
    cluster[10:22] = 10 + np.arange(12) // 4
    cluster[22:] = 20 + np.arange(8) // 4
    _, start = np.unique(cluster, return_index=True)
    n_clusters = start.size
    centre = np.array([p_joint[cluster == c].mean(axis=0) for c in np.unique(cluster)])
    eye = np.eye(4)
    p_world, n_world, got_link, distance, got_rows = kernels.mesh_sdf_contacts(
        eye,
        eye,
        np.eye(3)[None],
        np.zeros((1, 3)),
        p_joint,
        link,
        np.r_[start, link.size].astype(np.intp),
        centre,
        np.ones(n_clusters),
        np.zeros(n_clusters, dtype=np.intp),
        *sdf_lookup.grid_arguments(grid),
        0.0,
        k,
        np.zeros(link.size, dtype=np.bool_),
        0.0,
    )
    rows = top_k_per_link(link, np.full(link.size, -0.001), k)
    np.testing.assert_array_equal(rows, np.sort(rows))  # row order within each link
    np.testing.assert_array_equal(got_link, link[rows])
    np.testing.assert_array_equal(got_rows, rows)
    np.testing.assert_array_equal(p_world, p_joint[rows])
    np.testing.assert_array_equal(distance, np.float32(-0.001))
    assert np.all(np.isfinite(n_world))


@pytest.mark.parametrize("seed", range(6))
def test_kept_samples_keep_their_place_unless_one_is_closer_by_the_margin(seed):
    """On a grid whose distance is the x coordinate, the kernel's selection equals a stable
    top-K by ``distance - hysteresis * kept`` computed here, whatever was kept."""
    x = np.arange(6) * 0.01
    grid = SignedDistanceGrid(
        origin=np.zeros(3), spacing=0.01, values=np.broadcast_to(x[:, None, None], (6, 6, 6))
    )
    rng = np.random.default_rng(seed)
    link = np.repeat([0, 2], [9, 7])
    p_joint = rng.uniform(0.0, 0.05, (link.size, 3))
    p_joint[:, 0] = rng.uniform(0.0, 0.012, link.size)  # distances 0..12 mm
    kept = rng.random(link.size) < 0.4
    hysteresis, k, d_thresh = rng.uniform(0.0, 0.004), int(rng.integers(1, 5)), 0.01
    start = np.r_[0, 9, link.size].astype(np.intp)
    centre = np.array([p_joint[:9].mean(axis=0), p_joint[9:].mean(axis=0)])
    eye = np.eye(4)
    *_, distance, rows = kernels.mesh_sdf_contacts(
        eye, eye, np.eye(3)[None], np.zeros((1, 3)), p_joint, link, start, centre,
        np.ones(2), np.zeros(2, dtype=np.intp), *sdf_lookup.grid_arguments(grid),
        d_thresh, k, kept, hysteresis,
    )  # fmt: skip
    d = p_joint[:, 0]
    candidate = np.flatnonzero(d < d_thresh)
    key = d[candidate] - hysteresis * kept[candidate]
    want = candidate[top_k_per_link(link[candidate], key, k)]
    np.testing.assert_array_equal(rows, want)
    np.testing.assert_allclose(distance, d[want], atol=1e-7)  # float32 grid


def test_the_estimator_keeps_a_held_grasps_points_under_tracker_noise(allegro, cube):
    """A held cube whose tracked pose jitters by 0.2 mm and 0.2 deg: the paper's re-selection
    swaps points in almost every cycle, the 1 mm margin in a few; reset() forgets."""
    grasp = load_grasps("allegro_right", "077_rubiks_cube")[0]
    kin = HandKinematics(allegro)
    kin.update(grasp.q_array(allegro))
    wMo = grasp.object_pose(allegro.wMb)
    changes = {}
    for margin in (0.0, 0.001):
        est = MeshSDFEstimator(allegro, cube, hysteresis=margin)
        rng = np.random.default_rng(0)
        changed, previous = 0, None
        for _ in range(100):
            noise = pose_from_xyz_rpy(rng.normal(0, 2e-4, 3), rng.normal(0, np.radians(0.2), 3))
            est.estimate(kin, wMo @ noise)
            rows = set(est.rows.tolist())
            changed += previous is not None and rows != previous
            previous = rows
        changes[margin] = changed
        est.reset()
        assert est.rows.size == 0 and not est._kept.any()
    assert changes[0.0] >= 60
    assert changes[0.001] <= changes[0.0] // 3, changes


def test_a_bad_hysteresis_is_named(allegro, cube):
    for bad in (-0.001, 0.01, float("nan")):
        with pytest.raises(ConfigError, match="hysteresis must be >= 0 and below d_thresh"):
            MeshSDFEstimator(allegro, cube, hysteresis=bad)


def test_unit_normals_flags_degenerate_ones() -> None:
    from wholehand.contacts.normals import unit_normals

    n = np.array([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0], [0.0, 0.0, 0.0], [np.nan, 0.0, 1.0]])
    unit, every = unit_normals(n, 1e-3)
    np.testing.assert_array_equal(unit, [True, True, False, False])
    assert not every
    assert unit_normals(n[:2] * (1.0 + 4e-4), 1e-3)[1]  # |n|^2 - 1 = 8e-4 < 1e-3
