"""Contact estimation against analytic distances and normals of spheres and boxes."""

from __future__ import annotations

import numpy as np
import pytest
from wholehand_plugins.mesh_sdf.reference import top_k_per_link

from wholehand import registry
from wholehand.contacts.base import ContactSet
from wholehand.errors import ConfigError
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel
from wholehand.models.poses import inverse, pose_from_xyz_rpy

GRID_TOL = 1e-3  # [m], half of the 2 mm SDF grid spacing
RADIUS = 0.04
BOX = np.array([0.06, 0.08, 0.07])
# Just in front of the Allegro palm face (x = 11.1 mm in the base frame), 3 mm away.
PALM_FRONT_X = 0.0111


@pytest.fixture(scope="module")
def sphere():
    return ObjectModel.sphere(RADIUS, mass=0.2)


@pytest.fixture(scope="module")
def box():
    return ObjectModel.box(tuple(BOX), mass=0.3)


def sphere_pose(gap=0.003):
    return pose_from_xyz_rpy([PALM_FRONT_X + RADIUS + gap, 0.0, -0.05], [0.3, 0.2, 0.1])


def box_pose(gap=0.003):
    # Rotated about x only, so the face towards the palm stays parallel to it.
    return pose_from_xyz_rpy([PALM_FRONT_X + BOX[0] / 2 + gap, 0.0, -0.05], [0.2, 0.0, 0.0])


def closed_q(hand, fraction=0.5):
    return hand.q_lower + fraction * (hand.q_upper - hand.q_lower)


def estimator(name, hand, obj, **params):
    return registry.load("contact_estimators", name, hand=hand, obj=obj, **params)


def analytic_sphere(p_obj):
    r = np.linalg.norm(p_obj, axis=1)
    return r - RADIUS, p_obj / r[:, None]


def analytic_box(p_obj):
    half = BOX / 2
    q = np.abs(p_obj) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    d = outside + inside
    n = np.zeros_like(p_obj)
    out = outside > 0
    n[out] = np.sign(p_obj[out]) * np.maximum(q[out], 0.0) / outside[out, None]
    face = np.argmax(q[~out], axis=1)
    n_in = np.zeros((np.count_nonzero(~out), 3))
    n_in[np.arange(face.size), face] = np.sign(p_obj[~out][np.arange(face.size), face])
    n[~out] = n_in
    return d, n


def in_object_frame(contacts, wMo):
    oMw = inverse(wMo)
    return contacts.p_world @ oMw[:3, :3].T + oMw[:3, 3], contacts.n_world @ oMw[:3, :3].T


@pytest.mark.parametrize("fraction", [0.2, 0.5])
def test_sphere_distances_and_normals_are_analytic(allegro, sphere, fraction):
    kin = HandKinematics(allegro)
    kin.update(closed_q(allegro, fraction))
    wMo = sphere_pose()
    contacts = estimator("mesh_sdf", allegro, sphere).estimate(kin, wMo, stamp=2.0)
    assert len(contacts) > 0 and contacts.stamp == 2.0
    assert "palm_link" in {allegro.link_names[i] for i in contacts.link}
    p_obj, n_obj = in_object_frame(contacts, wMo)
    d_true, n_true = analytic_sphere(p_obj)
    np.testing.assert_allclose(contacts.distance, d_true, atol=GRID_TOL)
    cos = np.sum(n_obj * n_true, axis=1)
    assert np.all(cos > np.cos(np.deg2rad(5.0)))
    np.testing.assert_allclose(np.linalg.norm(contacts.n_world, axis=1), 1.0, atol=1e-6)


def test_box_distances_and_normals_are_analytic(allegro, box):
    kin = HandKinematics(allegro)
    kin.update(closed_q(allegro, 0.3))
    wMo = box_pose()
    contacts = estimator("mesh_sdf", allegro, box).estimate(kin, wMo)
    assert len(contacts) > 0
    p_obj, n_obj = in_object_frame(contacts, wMo)
    d_true, n_true = analytic_box(p_obj)
    np.testing.assert_allclose(contacts.distance, d_true, atol=GRID_TOL)
    # The box SDF has kinks where two faces are equally near (edges outside, the medial
    # surfaces inside); interpolated normals are exact two cells away from them.
    q = -np.sort(-(np.abs(p_obj) - BOX / 2), axis=1)
    away_from_edges = q[:, 0] - q[:, 1] > 0.004
    assert away_from_edges.sum() >= 3
    cos = np.sum(n_obj[away_from_edges] * n_true[away_from_edges], axis=1)
    assert np.all(cos > np.cos(np.deg2rad(5.0)))


def test_a_common_rigid_motion_leaves_contacts_unchanged_relative_to_the_object(allegro, sphere):
    est = estimator("mesh_sdf", allegro, sphere)
    q = closed_q(allegro, 0.4)
    kin = HandKinematics(allegro)
    kin.update(q, np.eye(4))
    wMo = sphere_pose()
    before = est.estimate(kin, wMo)
    T = pose_from_xyz_rpy([0.3, -1.2, 0.7], [1.0, -0.4, 2.5])
    kin.update(q, T @ np.eye(4))
    after = est.estimate(kin, T @ wMo)
    np.testing.assert_array_equal(before.link, after.link)
    p0, n0 = in_object_frame(before, wMo)
    p1, n1 = in_object_frame(after, T @ wMo)
    np.testing.assert_allclose(p1, p0, atol=1e-9)
    np.testing.assert_allclose(n1, n0, atol=1e-6)
    np.testing.assert_allclose(after.distance, before.distance, atol=1e-6)


def brute_force(hand, obj, kin, wMo, d_thresh, k):
    """Every sample through the SDF, then threshold and top-K by sorting per link."""
    p_obj = kin.transform_points(hand.samples.p_joint, hand.samples.joint, inverse(wMo))
    d = obj.sdf.query(p_obj)
    chosen = {}
    for link in np.unique(hand.samples.link):
        rows = np.flatnonzero((hand.samples.link == link) & (d < d_thresh))
        chosen[int(link)] = np.sort(d[rows])[:k]
    return {link: v for link, v in chosen.items() if v.size}


@pytest.mark.parametrize("d_thresh,k", [(0.01, 5), (0.005, 1), (0.02, 3)])
def test_threshold_and_top_k_match_brute_force(allegro, sphere, d_thresh, k):
    kin = HandKinematics(allegro)
    kin.update(closed_q(allegro, 0.5))
    wMo = sphere_pose(gap=0.001)
    contacts = estimator("mesh_sdf", allegro, sphere, d_thresh=d_thresh, k=k).estimate(kin, wMo)
    expected = brute_force(allegro, sphere, kin, wMo, d_thresh, k)
    got = {
        int(link): np.sort(contacts.distance[contacts.link == link])
        for link in np.unique(contacts.link)
    }
    assert got.keys() == expected.keys()
    for link in got:
        np.testing.assert_allclose(got[link], expected[link], atol=1e-6)
    assert np.all(contacts.distance < d_thresh)
    assert np.bincount(contacts.link).max() <= k


def test_link_filter_restricts_contacts(allegro, sphere):
    kin = HandKinematics(allegro)
    kin.update(closed_q(allegro, 0.6))
    wMo = sphere_pose()
    tips = [allegro.link_names[i] for i in np.flatnonzero(allegro.link_fingertip)]
    full = estimator("mesh_sdf", allegro, sphere).estimate(kin, wMo)
    only = estimator("mesh_sdf", allegro, sphere, links=tips).estimate(kin, wMo)
    assert np.all(only.fingertip)
    assert len(only) == np.count_nonzero(full.fingertip)


def test_far_object_gives_an_empty_set(allegro, sphere):
    kin = HandKinematics(allegro)
    for name in ("mesh_sdf", "coal_distance"):
        contacts = estimator(name, allegro, sphere).estimate(
            kin, pose_from_xyz_rpy([1, 1, 1], [0, 0, 0])
        )
        assert len(contacts) == 0
        assert contacts.link_actuated.shape == (len(allegro.link_names),)


@pytest.mark.parametrize("obj_name", ["sphere", "box"])
def test_estimators_agree_on_primitives(allegro, request, obj_name):
    obj = request.getfixturevalue(obj_name)
    wMo = sphere_pose() if obj_name == "sphere" else box_pose()
    analytic = analytic_sphere if obj_name == "sphere" else analytic_box
    kin = HandKinematics(allegro)
    kin.update(closed_q(allegro, 0.4))
    sdf_set = estimator("mesh_sdf", allegro, obj, d_thresh=0.015).estimate(kin, wMo)
    coal_set = estimator("coal_distance", allegro, obj, d_thresh=0.015).estimate(kin, wMo)
    assert len(coal_set) > 0
    # coal's witness points are exact: apart from each other, their analytic distance is what
    # coal reports; penetrating, coal reports the penetration depth, at least as deep as the
    # deepest witness point.
    p_obj, _ = in_object_frame(coal_set, wMo)
    d_true, _ = analytic(p_obj)
    apart = coal_set.distance >= 0.0
    np.testing.assert_allclose(coal_set.distance[apart], d_true[apart], atol=1e-6)
    assert np.all(coal_set.distance[~apart] <= d_true[~apart] + 1e-6)
    # Per link, no sample is closer than coal's exact minimum; where the link is apart from the
    # object, the closest sample of a surface sampled every ~7 mm is at most a few mm farther.
    for link in np.unique(coal_set.link):
        exact = coal_set.distance[coal_set.link == link].min()
        sampled = sdf_set.distance[sdf_set.link == link]
        name = allegro.link_names[link]
        if exact < 0.005:
            assert sampled.size, name
        if sampled.size:
            assert exact - GRID_TOL <= sampled.min(), name
            if exact >= 0.0:
                assert sampled.min() <= exact + 0.006, name


def test_bad_parameters_and_poses_raise(allegro, sphere):
    with pytest.raises(ConfigError, match="d_thresh"):
        estimator("mesh_sdf", allegro, sphere, d_thresh=-0.01)
    with pytest.raises(ConfigError, match="k must be"):
        estimator("mesh_sdf", allegro, sphere, k=0)
    with pytest.raises(ConfigError, match="not a link"):
        estimator("mesh_sdf", allegro, sphere, links=["thumb_nail"])
    est = estimator("mesh_sdf", allegro, sphere)
    bad = np.eye(4)
    bad[0, 3] = np.nan
    with pytest.raises(ConfigError, match="wMo.*NaN"):
        est.estimate(HandKinematics(allegro), bad)


def test_top_k_per_link_selection():
    link = np.array([2, 0, 2, 2, 0, 1])
    dist = np.array([0.3, 0.2, 0.1, 0.2, 0.1, 0.5])
    picked = top_k_per_link(link, dist, 2)
    assert sorted(zip(link[picked].tolist(), dist[picked].tolist(), strict=True)) == [
        (0, 0.1),
        (0, 0.2),
        (1, 0.5),
        (2, 0.1),
        (2, 0.2),
    ]
    assert top_k_per_link(link[:0], dist[:0], 2).size == 0


def test_contact_set_rejects_inconsistent_shapes(allegro):
    with pytest.raises(ConfigError, match="n_world"):
        ContactSet(
            p_world=np.zeros((2, 3)),
            n_world=np.zeros((3, 3)),
            link=np.zeros(2, dtype=np.intp),
            distance=np.zeros(2),
            link_actuated=allegro.link_actuated,
            link_fingertip=allegro.link_fingertip,
        )
