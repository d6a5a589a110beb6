"""The palm frame derived from a hand model (the grasp generator's placement frame)."""

from __future__ import annotations

import numpy as np
import pytest
from toy_hand import CLAW_RADIUS, write_claw_hand, write_toy_hand

from wholehand.errors import ConfigError
from wholehand.models.grasp_styles import style_arrays
from wholehand.models.hand import load_hand
from wholehand.models.palm import CLAW_REACH, model_palm_normal, palm_frame
from wholehand.models.poses import pose_from_xyz_rpy


def _power_palm(hand):
    q, tau, _ = style_arrays(hand, hand.config.grasp_styles["power"])
    return palm_frame(hand, q, tau)


def test_the_palm_frame_of_a_hand_whose_root_is_elsewhere(tmp_path):
    """The toy palm hangs from its root by a known transform: the palm frame is that rotation,
    and the face, top and middle are the palm link's planes x = 0, z = 0 and y = 0 seen from
    the root."""
    xyz, rpy = (0.01, 0.02, 0.03), (0.3, -0.5, 1.2)
    hand = load_hand(write_toy_hand(tmp_path / "toy", palm_xyz=xyz, palm_rpy=rpy))
    bMpalm = pose_from_xyz_rpy(xyz, rpy)
    palm = _power_palm(hand)
    np.testing.assert_allclose(palm.bRp, bMpalm[:3, :3], atol=1e-8)
    along = bMpalm[:3, :3].T @ bMpalm[:3, 3]  # the palm link's origin along the palm axes
    assert palm.face == pytest.approx(along[0], abs=1e-8)
    assert palm.centre[1] == pytest.approx(along[1], abs=1e-8)
    assert palm.top == pytest.approx(along[2], abs=1e-8)
    assert palm.centre[2] == pytest.approx(along[2] - 0.04, abs=1e-8)
    np.testing.assert_allclose(palm.to_palm(bMpalm[:3, 3]), along, atol=1e-12)


@pytest.mark.parametrize(
    ("name", "face", "top"),
    [("allegro_right", 0.0111, 0.0), ("robotis_hx5_d20_right", 0.021, 0.1224)],
)
def test_shipped_hands_close_toward_x_with_fingers_along_z(name, face, top):
    """Both shipped hands point their fingers along +z of their root and flex them toward +x
    (read off their URDFs); the Allegro's root sits at its knuckles, the HX5-D20's at the wrist."""
    palm = _power_palm(load_hand(name))
    np.testing.assert_array_equal(palm.bRp, np.eye(3))
    assert palm.face == pytest.approx(face, abs=1e-4)
    assert palm.top == pytest.approx(top, abs=1e-4)


def test_closing_torques_that_move_no_fingertip_are_named(tmp_path):
    hand = load_hand(write_toy_hand(tmp_path / "toy"))
    q, tau, _ = style_arrays(hand, hand.config.grasp_styles["power"])
    tau[:] = 0.0
    tau[hand.joint_names.index("t_j1")] = 0.1  # only the thumb closes
    with pytest.raises(ConfigError, match="do not move the tips of the fingers.*f1_2"):
        palm_frame(hand, q, tau)


def test_hand_toml_can_set_the_palm_normal_over_the_models(tmp_path):
    """The toy hand closes toward +x; a hand.toml that says the palm faces +x tilted toward +y
    gets that normal, made orthogonal to the fingers' direction; a zero normal is refused."""
    from wholehand.models.hand_config import parse_hand_config

    folder = write_toy_hand(tmp_path / "toy", top="palm_normal = [1.0, 1.0, 0.0]")
    hand = load_hand(folder)
    q, tau, _ = style_arrays(hand, hand.config.grasp_styles["power"])
    tau[:] = 0.0  # nothing closes: the given normal needs no closing motion
    palm = palm_frame(hand, q, tau)
    np.testing.assert_allclose(palm.bRp[:, 0], np.array([1.0, 1.0, 0.0]) / np.sqrt(2), atol=1e-9)
    np.testing.assert_allclose(palm.bRp.T @ palm.bRp, np.eye(3), atol=1e-12)
    zero = write_toy_hand(tmp_path / "zero", top="palm_normal = [0.0, 0.0, 0.0]")
    with pytest.raises(ConfigError, match="palm_normal must be a direction, not zero"):
        parse_hand_config(zero)
    bad = write_toy_hand(tmp_path / "bad", top='palm_normal = "x"')
    with pytest.raises(ConfigError, match="palm_normal must be a list of 3 finite numbers"):
        parse_hand_config(bad)


def test_a_claw_without_a_palm_closes_along_its_fingers(tmp_path):
    """Three fingers around the z axis closing toward it, behind them only a small hub: the
    tips' closing motions cancel, so the model's palm normal is the fingers' direction (+z),
    and the object's place is among the finger roots (face: their plane z = 0; top: the axis
    plus CLAW_REACH; centre: the axis), not in front of the hub. Every finger joint is a
    flexion motor closing with +q."""
    from wholehand.models.grasp_styles import derived_close_torque
    from wholehand.models.motor_roles import motor_roles

    hand = load_hand(write_claw_hand(tmp_path / "claw"))
    derived = derived_close_torque(hand)
    assert sorted(derived) == sorted(hand.joint_names) and min(derived.values()) > 0.0
    assert {r.role for r in motor_roles(hand).values()} == {"flexion"}
    q, tau, _ = style_arrays(hand, hand.config.grasp_styles["power"])
    tau = np.array([derived.get(j, 0.0) for j in hand.joint_names])
    np.testing.assert_allclose(model_palm_normal(hand, q, tau), [0.0, 0.0, 1.0], atol=1e-9)
    palm = palm_frame(hand, q, tau)
    np.testing.assert_allclose(palm.bRp[:, 0], [0.0, 0.0, 1.0], atol=1e-9)
    # z of the palm frame points from the axis to the first finger's root (x of the root).
    np.testing.assert_allclose(palm.bRp[:, 2], [1.0, 0.0, 0.0], atol=1e-9)
    assert palm.face == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(palm.centre, 0.0, atol=1e-9)
    assert palm.top == pytest.approx(CLAW_REACH)
    assert CLAW_REACH < CLAW_RADIUS  # the object's place stays inside the ring of roots


def test_a_thumb_at_the_palms_side_closes_across_the_palm(tmp_path):
    """A thumb turning about +z at the palm's side: a flexion motor, closing with +q (its tip
    moves toward +y, across the palm face); the palm normal is the fingers', +x."""
    from wholehand.models.grasp_styles import derived_close_torque
    from wholehand.models.motor_roles import motor_roles

    hand = load_hand(write_toy_hand(tmp_path / "side", side_thumb=True))
    assert motor_roles(hand)["t_j1"].role == "flexion"
    assert derived_close_torque(hand)["t_j1"] > 0.0
    q, tau, _ = style_arrays(hand, hand.config.grasp_styles["power"])
    np.testing.assert_allclose(model_palm_normal(hand, q, tau), [1.0, 0.0, 0.0], atol=1e-9)


def test_a_claw_with_a_thumb_is_still_a_claw_where_the_optimiser_starts(tmp_path):
    """Naming one claw finger the thumb (for power grasps) and starting from mid-range, where
    the curled tips also move back toward the hub together: the synthesiser's palm frame is
    still the claw's, its normal the fingers' direction (+z) over all three fingers."""
    from wholehand.grasps.generate import named_style
    from wholehand.grasps.synthesis import GraspSynthesizer
    from wholehand.models.grasp_styles import with_close_torque
    from wholehand.models.object_catalogue import load_object

    folder = write_claw_hand(tmp_path / "claw")
    toml = folder / "hand.toml"
    toml.write_text(toml.read_text().replace('palm_link = "hub"', 'palm_link = "hub"\nthumb = "a"'))
    hand = load_hand(folder)
    style = with_close_torque(hand, named_style(hand, "power"))
    palm = GraspSynthesizer(hand, load_object("058_golf_ball"), style).palm
    np.testing.assert_allclose(palm.bRp[:, 0], [0.0, 0.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(palm.centre[1:], 0.0, atol=1e-9)  # on the axis
