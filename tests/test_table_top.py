"""Table-top grasps: resting faces, the generator's table mode and the table's contact switch."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Delaunay

from wholehand import registry
from wholehand.backends.table import HAND_MARGIN, Table
from wholehand.errors import ConfigError
from wholehand.grasps.face_schedule import FaceSchedule
from wholehand.grasps.generate import GENERATOR_TABLE, MAX_TILT, GraspGenerator
from wholehand.grasps.store import grasp_file, hand_grasps_dir, load_grasps
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel
from wholehand.models.resting import (
    MIN_PROBABILITY,
    ROUND_FACES,
    RestingFace,
    resting_faces,
    resting_pose,
    up_rotation,
)

BOX = (0.07, 0.14, 0.168)
"""A box the Allegro's power pre-shape can reach from above without its thumb in the table."""


@pytest.fixture(scope="module")
def box() -> ObjectModel:
    return ObjectModel.box(BOX, mass=0.1, name="table_box")


def test_a_box_rests_on_its_six_faces_the_largest_most_likely(box):
    faces = resting_faces(box)
    ups = np.array([f.up for f in faces])
    assert len(faces) == 6
    # Each face's up is one of +-x, +-y, +-z.
    assert np.allclose(np.sort(np.abs(ups), axis=1), [[0, 0, 1]] * 6, atol=1e-9)
    # The largest faces (normal x, 14 x 16.8 cm) are the likeliest, the smallest (normal z) least.
    by_axis = {int(np.argmax(np.abs(f.up))): f.probability for f in faces}
    assert by_axis[0] > by_axis[1] > by_axis[2]
    assert sum(f.probability for f in faces) == pytest.approx(1.0, abs=1e-6)


def test_a_ball_rests_on_its_likeliest_faces_with_its_centre_over_them():
    """A sphere's hull has thousands of faces, none 2 % likely: it rests on the likeliest few,
    each a pose whose centre of mass lies over the face it stands on."""
    ball = ObjectModel.sphere(0.03, mass=0.05, name="ball")
    faces = resting_faces(ball)
    assert 1 <= len(faces) <= ROUND_FACES
    assert all(0.0 < f.probability < MIN_PROBABILITY for f in faces)
    for face in faces:
        wMo = resting_pose(ball, face.up, 0.0, (0.0, 0.0), 0.0)
        world = np.asarray(ball.mesh.vertices) @ wMo[:3, :3].T + wMo[:3, 3]
        low = world[world[:, 2] < 1e-6]  # the face it stands on
        assert len(low) >= 3
        com = wMo[:3, :3] @ ball.com + wMo[:3, 3]
        assert com[2] == pytest.approx(0.03, abs=1e-3)
        hull = Delaunay(low[:, :2])
        assert hull.find_simplex(com[:2]) >= 0


def test_resting_pose_puts_up_to_z_and_the_lowest_point_on_the_plane(box):
    up = np.array([0.0, 1.0, 0.0])
    wMo = resting_pose(box, up, 0.3, (0.2, -0.1), 0.75)
    assert wMo[:3, :3] @ up == pytest.approx([0, 0, 1])
    assert np.linalg.det(wMo[:3, :3]) == pytest.approx(1.0)
    world = np.asarray(box.mesh.vertices) @ wMo[:3, :3].T + wMo[:3, 3]
    assert world[:, 2].min() == pytest.approx(0.75)
    # Resting on a y face, the box's centre is half its y side (7 cm) above the plane.
    assert wMo[:3, 3] == pytest.approx([0.2, -0.1, 0.75 + BOX[1] / 2])
    # The yaw turns about world z.
    R0 = up_rotation(up, 0.0)
    assert R0.T @ wMo[:3, :3] @ up == pytest.approx(up)
    with pytest.raises(ConfigError, match="non-zero"):
        up_rotation(np.zeros(3))


def test_a_table_candidate_rests_the_object_and_brings_the_palm_from_above(allegro, box):
    generator = GraspGenerator(allegro, box, on_table=True)
    for index in range(20):
        face = generator.faces[index % len(generator.faces)]
        wMo, wMb = generator.table_candidate(np.random.default_rng([3, index]), face)
        world = np.asarray(box.mesh.vertices) @ wMo[:3, :3].T + wMo[:3, 3]
        assert world[:, 2].min() == pytest.approx(GENERATOR_TABLE.top, abs=1e-9)
        assert wMo[:3, :3] @ face.up == pytest.approx([0, 0, 1])
        normal = wMb[:3, :3] @ generator.palm.bRp[:, 0]  # palm normal, toward the object
        assert normal @ [0.0, 0.0, -1.0] >= np.cos(MAX_TILT) - 1e-9
        # The object lies on the palm's side: its centre is ahead of the palm face.
        centre = wMo[:3, :3] @ np.asarray(box.com) + wMo[:3, 3]
        assert (centre - wMb[:3, 3]) @ normal > generator.palm.face


def test_the_face_schedule_gives_each_face_its_share_of_the_grasps():
    faces = [RestingFace(np.eye(3)[i % 3], p) for i, p in enumerate([0.5, 0.3, 0.2])]
    schedule = FaceSchedule(faces, count=4)  # a share of 2 grasps per face
    assert schedule.share == 2
    # Fewest candidates first, the likelier face on a tie.
    assert schedule.next() == 0
    schedule.record(0, 16, 2)  # face 0 has its share
    assert schedule.next() == 1
    schedule.record(1, 16, 0)
    assert schedule.next() == 2
    schedule.record(2, 16, 1)
    # Faces 1 and 2 are short, face 0 no longer gets candidates although it has fewest ...
    schedule.record(1, 16, 2)
    assert schedule.next() == 2
    schedule.record(2, 32, 1)
    # ... and once every face has its share, all take turns again.
    assert schedule.found == [2, 2, 2]
    assert schedule.next() == 0
    with pytest.raises(ValueError, match="at least one"):
        FaceSchedule([], 3)


def test_table_top_candidates_take_the_faces_in_turn(allegro, box):
    generator = GraspGenerator(allegro, box, on_table=True)
    seen = []
    original = generator.try_candidate

    def spy(index, seed, face=None):
        seen.append(next(i for i, f in enumerate(generator.faces) if f is face))
        return original(index, seed, face)

    generator.try_candidate = spy
    generator.generate(count=len(generator.faces), seed=0, max_candidates=len(generator.faces))
    assert seen == list(range(len(generator.faces)))


def test_table_top_grasps_hold_without_the_table_and_clear_it(allegro, box):
    generator = GraspGenerator(allegro, box, on_table=True)
    grasps = generator.generate(count=2, seed=0, max_candidates=200)
    assert len(grasps) == 2, generator.rejections
    assert generator.rejections["the pre-shape reaches into the table"] > 0
    # One grasp asked for per face until every face has one: the two are on two faces.
    assert grasps[0].extra["table_up"] != grasps[1].extra["table_up"]
    assert sorted(generator.grasps_per_face, reverse=True)[:3] == [1, 1, 0]
    for grasp in grasps:
        up = np.asarray(grasp.extra["table_up"])
        assert any(np.allclose(up, f.up) for f in generator.faces)
        # Independently of the generator: with the box resting on that face, at any yaw, the
        # hand at the grasp stays HAND_MARGIN above the table.
        for yaw in (0.0, 2.0):
            wMo = resting_pose(box, up, yaw, (0.1, 0.2), 0.4)
            kin = HandKinematics(allegro)
            kin.update(grasp.q_array(allegro), wMo @ grasp.oMb)
            points = kin.transform_points(allegro.samples.p_joint, allegro.samples.joint)
            assert points[:, 2].min() >= 0.4 + HAND_MARGIN
    again = GraspGenerator(allegro, box, on_table=True).generate(2, 0, 200)
    assert [g.oMb.tolist() for g in again] == [g.oMb.tolist() for g in grasps]


def test_the_table_contact_switch_lets_an_object_fall_through(allegro, box):
    table = Table(top=0.0, size=(0.5, 0.5))
    wMo = resting_pose(box, np.array([1.0, 0.0, 0.0]), 0.0, (0.0, 0.0), 0.0)
    far = np.eye(4)
    far[:3, 3] = [0.0, 0.0, 1.0]  # the hand well above, out of the way
    backend = registry.load(
        "backends", "mujoco", hand=allegro, obj=box, wMo_init=wMo, gravity=True, table=table,
        base="mocap", wMb=far,
    )  # fmt: skip
    backend.step(0.3)
    assert backend.observe().wMo[2, 3] == pytest.approx(wMo[2, 3], abs=2e-3)  # rests
    backend.set_table_contact(False)
    backend.step(0.3)
    fallen = 0.5 * 9.81 * 0.3**2
    assert backend.observe().wMo[2, 3] == pytest.approx(wMo[2, 3] - fallen, abs=0.02)
    plain = registry.load("backends", "mujoco", hand=allegro, obj=box)
    with pytest.raises(ConfigError, match="no table"):
        plain.set_table_contact(True)


def test_table_top_grasps_have_their_own_folder_and_the_error_names_the_flag():
    folder = hand_grasps_dir("allegro_right")
    assert grasp_file("allegro_right", "x", on_table=True) == folder / "on_table" / "x.json"
    assert (
        grasp_file("allegro_right", "x", "precision", on_table=True)
        == folder / "precision" / "on_table" / "x.json"
    )
    with pytest.raises(ConfigError, match="--on-table"):
        load_grasps("allegro_right", "052_extra_large_clamp", on_table=True)  # none on a table
