"""The ``mink`` reacher's object clearance limit against ground truth: its rows are the hand
samples nearest the object (brute force over every sample in the SDF), its bounds are their
distances, and its Jacobian rows are the SDF normal times the samples' velocity by finite
differences of the IK model's configuration."""

from __future__ import annotations

import numpy as np
import pytest

from wholehand import registry
from wholehand.models.kinematics import HandKinematics

GAIN, CLEARANCE, DETECTION, PER_LINK = 0.85, 0.005, 0.02, 3
DT = 0.005


@pytest.fixture(scope="module")
def cube(allegro):
    from wholehand.models.object_catalogue import load_object

    return load_object("077_rubiks_cube")


@pytest.fixture
def near_cube(allegro, cube):
    """A reacher whose hand (neutral angles, base at the origin) has the cube 8 mm past its
    lowest surface sample, and the samples' world points and distances to the cube."""
    reacher = registry.load("reachers", "mink", hand=allegro, obj=cube, table=None)
    q, wMb = allegro.neutral(), np.eye(4)
    kin = HandKinematics(allegro)
    kin.update(q, wMb)
    samples = allegro.samples
    points = kin.transform_points(samples.p_joint, samples.joint)
    lowest = points[np.argmin(points[:, 2])]
    wMo = np.eye(4)
    wMo[:3, 3] = lowest - [0.0, 0.0, 0.008 + 0.5 * cube.extents[2]]
    reacher._set_state(q, wMb, wMo)
    distance = cube.sdf.query(points - wMo[:3, 3])
    return reacher, points, distance, wMo


def _limit(reacher):
    from wholehand_plugins.reach_limits import ObjectClearanceLimit

    return ObjectClearanceLimit(reacher, reacher.obj, GAIN, CLEARANCE, DETECTION, PER_LINK)


def test_the_rows_are_the_samples_nearest_the_object_per_link(allegro, near_cube) -> None:
    reacher, points, distance, _ = near_cube
    G, h = _limit(reacher).compute_qp_inequalities(reacher.configuration, DT)
    link = allegro.samples.link
    expected = []
    for i in np.unique(link[distance < DETECTION]):
        mine = np.sort(distance[(link == i) & (distance < DETECTION)])
        expected.extend(mine[:PER_LINK])
    assert len(expected) >= 3  # the case is not empty: several links reach the cube
    assert G.shape == (len(expected), reacher.model.nv)
    got = h * DT / GAIN + CLEARANCE  # each row's distance, from its bound
    np.testing.assert_allclose(np.sort(got), np.sort(expected), atol=1e-9)


def test_each_row_is_the_normal_times_the_samples_velocity(allegro, cube, near_cube) -> None:
    reacher, points, distance, wMo = near_cube
    G, h = _limit(reacher).compute_qp_inequalities(reacher.configuration, DT)
    samples = allegro.samples
    configuration = reacher.configuration
    q0 = configuration.q.copy()
    rng = np.random.default_rng(3)
    v = rng.normal(scale=0.2, size=reacher.model.nv)
    eps = 1e-6
    configuration.update(configuration.integrate(v, eps))
    kin = HandKinematics(allegro)
    kin.update(*reacher.hand_state())
    moved = kin.transform_points(samples.p_joint, samples.joint)
    configuration.update(q0)
    for k in range(len(h)):
        d = h[k] * DT / GAIN + CLEARANCE
        i = int(np.argmin(np.abs(distance - d)))  # the sample of row k (distances differ)
        assert abs(distance[i] - d) < 1e-9
        _, grad = cube.sdf.query_with_gradient((points[i] - wMo[:3, 3])[None])
        n = grad[0] / np.linalg.norm(grad[0])
        velocity = (moved[i] - points[i]) / eps
        assert G[k] @ v == pytest.approx(-(n @ velocity), rel=1e-4, abs=1e-6)


def test_far_from_the_object_the_limit_has_no_rows(allegro, near_cube) -> None:
    reacher, _, _, wMo = near_cube
    far = wMo.copy()
    far[:3, 3] += [0.0, 0.0, -0.5]
    reacher._set_state(allegro.neutral(), np.eye(4), far)
    constraint = _limit(reacher).compute_qp_inequalities(reacher.configuration, DT)
    assert constraint.G is None and constraint.h is None


def test_an_object_grid_too_small_for_the_detection_distance_is_named(allegro) -> None:
    from wholehand.errors import ConfigError
    from wholehand.models.objects import ObjectModel

    small = ObjectModel.sphere(0.03, mass=0.1, name="ball", sdf_padding=0.012)
    with pytest.raises(ConfigError, match=r"detection.*'ball'.*sdf_padding above 0.02 m"):
        registry.load("reachers", "mink", hand=allegro, obj=small, table=None)
    registry.load("reachers", "mink", hand=allegro, obj=small, table=None, detection=0.008)
