"""Hand loading, link table, surface samples, their cache, and every bad input."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

from wholehand.errors import AssetError, ConfigError
from wholehand.models import hand_samples
from wholehand.models.hand import load_hand
from wholehand.models.hand_config import parse_hand_config
from wholehand.models.hand_folders import shipped_hands_dir


def test_allegro_loads_with_expected_structure(allegro):
    assert allegro.nq == allegro.nv == 16
    assert allegro.actuated_dofs.all()
    np.testing.assert_allclose(allegro.tau_max, 0.2)
    assert len(allegro.link_names) == 21
    palm = allegro.link_index("palm_link")
    assert not allegro.link_actuated[palm]
    assert allegro.link_actuated.sum() == 20
    assert allegro.link_fingertip.sum() == 8
    assert allegro.link_finger[allegro.link_index("link_15.0_tip")] == "thumb"


def test_candidate_count_and_density_match_link_areas(allegro):
    counts = np.bincount(allegro.samples.link, minlength=len(allegro.link_names))
    for i, name in enumerate(allegro.link_names):
        area_cm2 = allegro.link_mesh(i).area * 1e4
        assert counts[i] == max(1, round(2.0 * area_cm2)), name
    # link_1.0's collision box is 19.6 x 27.5 x 54 mm: area by hand, 2 points per cm^2.
    a, b, c = 1.96, 2.75, 5.4
    expected = 2.0 * 2.0 * (a * b + a * c + b * c)
    got = counts[allegro.link_index("link_1.0")]
    assert abs(got - expected) <= 0.1 * expected
    assert 2000 <= len(allegro.samples) <= 3000


def test_samples_lie_on_the_link_surface(allegro):
    i = allegro.link_index("link_1.0")  # box 19.6 x 27.5 x 54 mm centred at z = 27 mm
    pts = allegro.samples.p_joint[allegro.samples.link == i] - [0.0, 0.0, 0.027]
    half = np.array([0.0098, 0.01375, 0.027])
    # Every point is on the box boundary: inside-or-on, and on at least one face.
    assert np.all(np.abs(pts) <= half + 1e-9)
    assert np.all(np.min(half - np.abs(pts), axis=1) < 1e-9)
    tip = allegro.link_index("link_3.0_tip")
    tip_pts = allegro.samples.p_joint[allegro.samples.link == tip]
    (sphere,) = [
        g for g in allegro.collision_model.geometryObjects if g.name.startswith("link_3.0_tip")
    ]
    centre = sphere.placement.translation
    np.testing.assert_allclose(np.linalg.norm(tip_pts - centre, axis=1), 0.012, atol=2e-4)


def test_farthest_point_samples_are_spread(allegro):
    from scipy.spatial import cKDTree

    i = allegro.link_index("palm_link")
    pts = allegro.samples.p_joint[allegro.samples.link == i]
    spacing = cKDTree(pts).query(pts, k=2)[0][:, 1]
    # 2 points per cm^2 is one point per 0.5 cm^2: spacing about 7 mm; none closer than 2 mm.
    assert spacing.min() > 0.002
    assert 0.004 < np.median(spacing) < 0.010


def test_second_load_uses_the_cache(fresh_cache, monkeypatch):
    first = load_hand("allegro_right")
    assert not first.samples_from_cache

    def fail(*args, **kwargs):
        raise AssertionError("resampled although the cache holds the samples")

    monkeypatch.setattr(hand_samples, "sample_link_surface", fail)
    second = load_hand("allegro_right")
    assert second.samples_from_cache
    np.testing.assert_array_equal(first.samples.p_joint, second.samples.p_joint)
    # A different parameter is a different key: it must sample again.
    with pytest.raises(AssertionError, match="resampled"):
        load_hand("allegro_right", density_per_cm2=1.0)


# --- bad input ----------------------------------------------------------------------------------

URDF = """<?xml version="1.0"?>
<robot name="tiny">
  <link name="base"><collision><geometry>{base_geom}</geometry></collision>
    <inertial><mass value="0.1"/>
      <inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial>
  </link>
  <link name="finger"><collision><geometry><box size="0.01 0.01 0.04"/></geometry></collision>
    <inertial><mass value="0.01"/>
      <inertia ixx="1e-6" iyy="1e-6" izz="1e-6" ixy="0" ixz="0" iyz="0"/></inertial>
  </link>
  <joint name="j1" type="{joint_type}"><parent link="base"/><child link="finger"/>
    <axis xyz="0 1 0"/><limit lower="0" upper="1.5" effort="1" velocity="1"/></joint>
</robot>
"""

TOML = """
name = "tiny"
urdf = "tiny.urdf"
palm_link = "{palm}"
fingertip_links = ["finger"]
[fingers]
one = ["finger"]
[joints]
actuated = ["{joint}"]
"""


def write_hand(
    tmp_path,
    base_geom='<box size="0.05 0.05 0.01"/>',
    joint_type="revolute",
    palm="base",
    joint="j1",
    extra="",
):
    folder = tmp_path / "tiny"
    folder.mkdir(exist_ok=True)
    (folder / "tiny.urdf").write_text(URDF.format(base_geom=base_geom, joint_type=joint_type))
    (folder / "hand.toml").write_text(textwrap.dedent(extra) + TOML.format(palm=palm, joint=joint))
    return folder


def test_a_user_hand_loads_from_its_folder(tmp_path):
    hand = load_hand(write_hand(tmp_path))
    assert hand.nv == 1 and hand.link_names == ["base", "finger"]
    assert list(hand.link_actuated) == [False, True]


def test_missing_hand_config():
    with pytest.raises(ConfigError, match="no hand named 'nope'.*allegro_right"):
        load_hand("nope")


def test_missing_urdf(tmp_path):
    folder = write_hand(tmp_path)
    (folder / "tiny.urdf").unlink()
    with pytest.raises(AssetError, match="tiny.urdf does not exist"):
        load_hand(folder)


def test_malformed_urdf(tmp_path):
    folder = write_hand(tmp_path)
    (folder / "tiny.urdf").write_text("<robot name='x'><link name='a'>")
    with pytest.raises(AssetError, match="tiny.urdf"):
        load_hand(folder)


def test_unknown_link_lists_valid_links(tmp_path):
    with pytest.raises(ConfigError, match="'hand' is not a link.*'base'.*'finger'"):
        load_hand(write_hand(tmp_path, palm="hand"))


def test_unknown_joint_lists_valid_joints(tmp_path):
    with pytest.raises(ConfigError, match="'j9' is not a moving joint.*'j1'"):
        load_hand(write_hand(tmp_path, joint="j9"))


def test_missing_mesh_names_searched_directories(tmp_path):
    folder = write_hand(tmp_path, base_geom='<mesh filename="package://nowhere/palm.stl"/>')
    with pytest.raises(AssetError) as info:
        load_hand(folder)
    message = str(info.value)
    assert "package://nowhere/palm.stl" in message and str(folder) in message


def test_unsupported_joint_type(tmp_path):
    with pytest.raises(ConfigError, match="joint 'j1'.*not support"):
        load_hand(write_hand(tmp_path, joint_type="continuous"))


def test_unknown_key_and_bad_values(tmp_path):
    folder = write_hand(tmp_path, extra="colour = 'red'\n")
    with pytest.raises(ConfigError, match="unknown keys \\['colour'\\]"):
        parse_hand_config(folder)
    folder = write_hand(tmp_path, extra="sample_surface = 'skin'\n")
    with pytest.raises(ConfigError, match="sample_surface"):
        parse_hand_config(folder)
    folder = write_hand(tmp_path)
    text = (folder / "hand.toml").read_text() + "[simulation]\ndampign = 0.1\n"
    (folder / "hand.toml").write_text(text)
    with pytest.raises(ConfigError, match="unknown keys \\['dampign'\\] in \\[simulation\\]"):
        parse_hand_config(folder)


def test_negative_torque_limit(tmp_path):
    folder = write_hand(tmp_path)
    text = (
        (folder / "hand.toml")
        .read_text()
        .replace('actuated = ["j1"]', 'actuated = ["j1"]\ntorque_limit = { default = -0.2 }')
    )
    (folder / "hand.toml").write_text(text)
    with pytest.raises(ConfigError, match="torque_limit.default must be > 0"):
        parse_hand_config(folder)


def test_invalid_toml(tmp_path):
    folder = write_hand(tmp_path)
    (folder / "hand.toml").write_text("name = ")
    with pytest.raises(ConfigError, match="not valid TOML"):
        parse_hand_config(folder)


def test_distribution_that_is_not_installed(tmp_path):
    folder = write_hand(tmp_path)
    text = (
        (folder / "hand.toml")
        .read_text()
        .replace('urdf = "tiny.urdf"', 'urdf = { distribution = "no-such-dist", path = "x.urdf" }')
    )
    (folder / "hand.toml").write_text(text)
    with pytest.raises(AssetError, match="no-such-dist.*pip install"):
        parse_hand_config(folder)


def test_shipped_hand_folder_has_readme():
    assert (shipped_hands_dir() / "allegro_right" / "README.md").is_file()


def _with_grasping(folder, table):
    text = (
        (folder / "hand.toml")
        .read_text()
        .replace('fingertip_links = ["finger"]', 'fingertip_links = ["finger"]\nthumb = "one"')
    )
    (folder / "hand.toml").write_text(text + textwrap.dedent(table))
    return folder


def test_grasp_styles_are_parsed_and_checked(tmp_path):
    folder = _with_grasping(
        write_hand(tmp_path),
        """
        [grasping]
        close_torque = { j1 = 0.1 }
        [grasping.precision]
        preshape = { j1 = 0.2 }
        close_torque = { j1 = 0.05 }
        fingers = ["one"]
        palm_gap = [0.01, 0.02]
        """,
    )
    styles = load_hand(folder).config.grasp_styles
    assert set(styles) == {"power", "precision"}
    power, precision = styles["power"], styles["precision"]
    assert power.close_torque == {"j1": 0.1} and power.fingers == ()
    assert precision.preshape == {"j1": 0.2} and precision.fingers == ("one",)
    assert precision.palm_gap == (0.01, 0.02)


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ('fingers = ["one"]\ncolour = 1', "unknown keys \\['colour'\\]"),
        ('fingers = ["two"]', "fingers = \\['two'\\] must name the thumb"),
        ("fingers = []", "must name the thumb"),
        ('fingers = ["one"]\npalm_gap = [0.03, 0.01]', "palm_gap must be \\[low, high\\]"),
        ('fingers = ["one"]\npalm_gap = 0.01', "palm_gap"),
        ('fingers = ["one"]\nclose_torque = { j1 = "strong" }', "close_torque.j1 must be"),
    ],
)
def test_bad_grasp_style_raises(tmp_path, table, message):
    folder = _with_grasping(write_hand(tmp_path), "[grasping.precision]\n" + table + "\n")
    with pytest.raises(ConfigError, match=message):
        parse_hand_config(folder)


def test_grasp_style_with_unknown_joint_lists_valid_joints(tmp_path):
    folder = _with_grasping(
        write_hand(tmp_path), '[grasping.precision]\nfingers = ["one"]\npreshape = { j7 = 0.1 }\n'
    )
    with pytest.raises(ConfigError, match="'j7' is not a moving joint.*'j1'"):
        load_hand(folder)


@pytest.mark.parametrize("value", ['"origin"', "[0.0, 0.0]", '[0.0, "a", 0.0]', "[nan, 0.0, 0.0]"])
def test_mount_xyz_must_be_three_finite_numbers(tmp_path, value):
    folder = write_hand(tmp_path)
    with open(folder / "hand.toml", "a") as toml:
        toml.write(f"[mount]\nxyz = {value}\n")
    with pytest.raises(ConfigError, match="\\[mount\\] xyz must be a list of 3 finite numbers"):
        load_hand(folder)
