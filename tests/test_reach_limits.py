"""The ``mink`` reacher's clearance limits against ground truth: the object limit's rows are
the hand samples nearest the object (brute force over every sample in the SDF), its bounds
follow from their distances, and its Jacobian rows are the SDF normal times the samples'
velocity by finite differences of the IK model's configuration; one IK step under either limit
closes at most ``gain`` of each sample's gap above the clearance (positions after the step)."""

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


def _row_distances(reacher, limit):
    """The distances of ``limit``'s rows, in their order (its nearest-sample search)."""
    return limit.nearest.estimate(reacher.hand_kinematics(), reacher.object_pose()).distance


def _palm_step_down(reacher, limit, depth: float) -> None:
    """One IK step of ``reacher``'s model whose only task sends the palm ``depth`` [m] down
    (world z), under ``limit`` alone."""
    import mink

    configuration, palm_link = reacher.configuration, reacher.hand.palm_link
    palm = configuration.get_transform_frame_to_world(palm_link, "body").as_matrix()
    palm[2, 3] -= depth
    task = mink.FrameTask(palm_link, "body", position_cost=1.0, orientation_cost=1.0)
    task.set_target(mink.SE3.from_matrix(palm))
    v = mink.solve_ik(configuration, [task], DT, reacher.solver, damping=1e-6, limits=[limit])
    configuration.integrate_inplace(v, DT)


def test_the_rows_are_the_samples_nearest_the_object_per_link(allegro, near_cube) -> None:
    """Rows: the nearest samples per link (brute force over every sample); bounds: ``gain
    (d - clearance)``, a displacement (mink's variable), negative within the clearance."""
    reacher, points, distance, _ = near_cube
    limit = _limit(reacher)
    G, h = limit.compute_qp_inequalities(reacher.configuration, DT)
    link = allegro.samples.link
    expected = []
    for i in np.unique(link[distance < DETECTION]):
        mine = np.sort(distance[(link == i) & (distance < DETECTION)])
        expected.extend(mine[:PER_LINK])
    expected = np.sort(expected)
    assert len(expected) >= 3  # the case is not empty: several links reach the cube
    assert expected[0] < CLEARANCE < expected[-1]  # rows on both sides of the clearance
    assert G.shape == (len(expected), reacher.model.nv)
    np.testing.assert_allclose(np.sort(_row_distances(reacher, limit)), expected, atol=1e-9)
    np.testing.assert_allclose(np.sort(h), GAIN * (expected - CLEARANCE), atol=1e-9)


def test_each_row_is_the_normal_times_the_samples_velocity(allegro, cube, near_cube) -> None:
    reacher, points, distance, wMo = near_cube
    limit = _limit(reacher)
    G, h = limit.compute_qp_inequalities(reacher.configuration, DT)
    row_distance = _row_distances(reacher, limit)
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
        d = row_distance[k]
        i = int(np.argmin(np.abs(distance - d)))  # the sample of row k (distances differ)
        assert abs(distance[i] - d) < 1e-9
        _, grad = cube.sdf.query_with_gradient((points[i] - wMo[:3, 3])[None])
        n = grad[0] / np.linalg.norm(grad[0])
        velocity = (moved[i] - points[i]) / eps
        assert G[k] @ v == pytest.approx(-(n @ velocity), rel=1e-4, abs=1e-6)


def test_one_step_closes_at_most_gain_of_each_gap(allegro, cube, near_cube) -> None:
    """The bound is on the step's displacement (mink's variable): a step whose task pulls the
    palm 5 cm into the cube leaves each constrained sample at least ``(1 - gain)`` of its gap
    above the clearance (distances by brute force after the step; first order: within
    0.3 mm). A bound divided by dt, as for a velocity, lets the hand into the cube."""
    reacher, points, _, wMo = near_cube
    away = wMo.copy()
    away[:3, 3] += [0.0, 0.0, -0.03]  # every sample 1 cm or more from the cube
    reacher._set_state(allegro.neutral(), np.eye(4), away)
    limit = _limit(reacher)
    before = _row_distances(reacher, limit)
    assert len(before) >= 3 and before.min() > CLEARANCE  # every row above the clearance
    distance = cube.sdf.query(points - away[:3, 3])
    rows = [int(np.argmin(np.abs(distance - d))) for d in before]  # each row's sample
    _palm_step_down(reacher, limit, 0.05)
    kin = HandKinematics(allegro)
    kin.update(*reacher.hand_state())
    samples = allegro.samples
    moved = kin.transform_points(samples.p_joint[rows], samples.joint[rows])
    after = cube.sdf.query(moved - away[:3, 3])
    assert np.all(after >= CLEARANCE + (1.0 - GAIN) * (before - CLEARANCE) - 3e-4), after
    nearest = int(np.argmin(before))  # and the step went as far as the bound lets it
    assert after[nearest] == pytest.approx(
        CLEARANCE + (1.0 - GAIN) * (before[nearest] - CLEARANCE), abs=3e-4
    )


def test_one_step_above_the_table_closes_at_most_gain_of_each_gap(allegro, cube) -> None:
    """The table's limit bounds the step's displacement the same way: the palm pulled 5 cm
    down from 15 mm above the table top, every sample stays at least ``(1 - gain)``
    of its gap above the clearance, and the lowest ends at that bound (first order)."""
    from wholehand_plugins.reach_limits import TableLimit

    from wholehand.backends.table import Table
    from wholehand.models.kinematics import lowest_point

    table = Table(top=0.0)
    reacher = registry.load("reachers", "mink", hand=allegro, obj=cube, table=table)
    q, wMb = allegro.neutral(), np.eye(4)
    wMb[2, 3] = 0.015 - lowest_point(allegro, q, np.eye(4))  # lowest sample 15 mm up
    far = np.eye(4)
    far[:3, 3] = [1.0, 1.0, 1.0]
    reacher._set_state(q, wMb, far)
    limit = TableLimit(reacher, table, GAIN, CLEARANCE, DETECTION)
    samples = allegro.samples
    kin = HandKinematics(allegro)
    kin.update(q, wMb)
    before = kin.transform_points(samples.p_joint, samples.joint)[:, 2]
    assert before.min() == pytest.approx(0.015)
    _palm_step_down(reacher, limit, 0.05)
    kin.update(*reacher.hand_state())
    after = kin.transform_points(samples.p_joint, samples.joint)[:, 2]
    near = before < CLEARANCE + DETECTION
    bound = CLEARANCE + (1.0 - GAIN) * (before - CLEARANCE)
    assert np.all(after[near] >= bound[near] - 3e-4)
    lowest = int(np.argmin(before))
    assert after[lowest] == pytest.approx(bound[lowest], abs=3e-4)


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


def test_the_table_rows_come_from_each_links_convex_hull() -> None:
    """Of a box's 8 corners and 20 points inside it, the corners; of a flat set, every point."""
    from wholehand_plugins.reach_limits import _hull_samples

    rng = np.random.default_rng(0)
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 2) for z in (0, 3)], dtype=float)
    inside = rng.uniform(0.1, 0.9, size=(20, 3)) * [1, 2, 3]
    points = np.vstack([inside[:10], corners, inside[10:]])
    rows = np.arange(len(points)) + 100  # row indices into a larger sample array
    p_joint = np.zeros((200, 3))
    p_joint[rows] = points
    np.testing.assert_array_equal(_hull_samples(rows, p_joint), np.arange(110, 118))
    flat = rows.copy()
    p_joint[flat, 2] = 0.0
    np.testing.assert_array_equal(_hull_samples(flat, p_joint), flat)
