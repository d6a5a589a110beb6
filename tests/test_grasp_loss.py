"""The grasp-loss criterion: hull of fingertips and palm against the object's bounding box."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog
from scipy.spatial.transform import Rotation

from wholehand.grasps.store import load_grasps
from wholehand.loop.grasp_loss import (
    CLEAR_MARGIN,
    LINEAR_SUPPORT_MAX_POINTS,
    GraspLossCheck,
    clear_verdict,
)
from wholehand.models.kinematics import HandKinematics
from wholehand.models.object_catalogue import load_object


def hull_meets_box(points: np.ndarray, wMo: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Ground truth by linear programming: is some convex combination of the points inside the
    box [lo, hi] of the object frame?"""
    p_object = (points - wMo[:3, 3]) @ wMo[:3, :3]  # (M, 3) in the object frame
    A = p_object.T
    result = linprog(
        np.zeros(len(points)),
        A_ub=np.vstack([A, -A]),
        b_ub=np.r_[hi, -lo],
        A_eq=np.ones((1, len(points))),
        b_eq=[1.0],
        bounds=(0, None),
        method="highs",
    )
    return result.status == 0


def random_case(rng, hand, kin, check, obj) -> tuple[np.ndarray, np.ndarray]:
    """Hull points of a random hand configuration, and an object pose whose box centre lies
    near them, spread so that both outcomes occur, many near the border."""
    kin.update(rng.uniform(hand.q_lower, hand.q_upper), hand.wMb)
    points = check.hull_points(kin)
    wMo = np.eye(4)
    wMo[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    wMo[:3, 3] = points.mean(axis=0) + rng.normal(scale=0.06, size=3) - wMo[:3, :3] @ obj.com
    return points, wMo


@pytest.mark.parametrize("scan_only", [True, False])
def test_held_matches_the_exact_hull_box_intersection(allegro, scan_only):
    cube = load_object("077_rubiks_cube")
    check = GraspLossCheck(allegro, cube)
    assert check._scan_only == (len(check._p_joint) <= LINEAR_SUPPORT_MAX_POINTS)
    check._scan_only = scan_only
    kin = HandKinematics(allegro)
    lo, hi = cube.mesh.bounds
    rng = np.random.default_rng(7)
    outcomes = []
    for _ in range(150):
        points, wMo = random_case(rng, allegro, kin, check, cube)
        expected = hull_meets_box(points, wMo, lo, hi)
        assert check.held(kin, wMo) == expected
        assert check._gjk(points, wMo @ check._oMbox) == expected  # without the clear cases
        outcomes.append(expected)
    assert 0.2 < np.mean(outcomes) < 0.8


def test_clear_verdicts_are_the_exact_ones_and_common(allegro):
    cube = load_object("077_rubiks_cube")
    check = GraspLossCheck(allegro, cube)
    kin = HandKinematics(allegro)
    lo, hi = cube.mesh.bounds
    rng = np.random.default_rng(8)
    verdicts = []
    for _ in range(300):
        points, wMo = random_case(rng, allegro, kin, check, cube)
        wMbox = wMo @ check._oMbox
        verdict = clear_verdict(points, wMbox, check._half, check._n_tips, CLEAR_MARGIN)
        if verdict >= 0:
            assert bool(verdict) == hull_meets_box(points, wMo, lo, hi)
        verdicts.append(verdict)
    # Both answers are given without GJK, and some cases are left to it.
    assert {-1, 0, 1} <= set(verdicts)


def test_a_stored_grasp_is_held_and_a_removed_object_is_not(allegro):
    cube = load_object("077_rubiks_cube")
    grasp = load_grasps("allegro_right", "077_rubiks_cube")[0]
    check, kin = GraspLossCheck(allegro, cube), HandKinematics(allegro)
    kin.update(grasp.q_array(allegro), allegro.wMb)
    wMo = grasp.object_pose(allegro.wMb)
    assert check.held(kin, wMo)
    away = wMo.copy()
    away[:3, 3] += [0.0, 0.0, 0.5]  # half a metre along the fingers
    assert not check.held(kin, away)
