"""``wholehand hand check``: a hand folder's contents and findings, each with its fix."""

from __future__ import annotations

import json

import numpy as np
import pytest
from toy_hand import write_toy_hand

from wholehand.cli.main import main


def test_a_shipped_hand_is_usable_and_its_samples_are_drawn(tmp_path, capsys):
    png = tmp_path / "samples.png"
    assert main(["hand", "check", "allegro_right", "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert "16 joints, 16 actuated" in out and "usable" in out and "NOT usable" not in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_findings_name_the_problem_and_the_fix(tmp_path, capsys):
    """The toy hand with a palm box buried in the palm, a finger joint whose limits are the
    wrong way round would not load: checked on the first, then the second."""
    folder = write_toy_hand(tmp_path / "toy", knuckle=True, mimic=True)
    assert main(["hand", "check", str(folder), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["ok"] is True
    buried = [f for f in report["findings"] if "inside other collision shapes" in f["what"]]
    assert len(buried) == 1 and buried[0]["fix"] == "set outer_surface_only = true in hand.toml"
    assert report["summary"]["buried_samples"] > 10
    follows = {j["name"]: j["follows"] for j in report["joints"]}
    assert follows["f1_j2"] == "f1_j1" and follows["f1_j1"] is None
    coupling = {j["name"]: (j["multiplier"], j["offset"]) for j in report["joints"]}
    assert coupling["f1_j2"] == pytest.approx((0.8, 0.1)) and coupling["f1_j1"] == (None, None)
    # Real-looking efforts (1 N*m) that the default torque limit (0.2 N*m) replaces: said.
    unused = [f for f in report["findings"] if "that wholehand does not use" in f["what"]]
    assert len(unused) == 1 and "5 joints" in unused[0]["what"] and "f1_j1 (1)" in unused[0]["what"]
    # No torque_limit in hand.toml and placeholder efforts in the URDF.
    urdf = folder / "toy.urdf"
    urdf.write_text(urdf.read_text().replace('effort="1"', 'effort="1000"'))
    assert main(["hand", "check", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "WARNING: 5 joints have URDF effort limits that look like placeholders" in out
    assert "fix: set [joints] torque_limit in hand.toml" in out

    text = urdf.read_text()
    urdf.write_text(text.replace('lower="-0.2" upper="1.6"', 'lower="1.6" upper="-0.2"', 1))
    assert main(["hand", "check", str(folder)]) == 1
    out = capsys.readouterr().out
    assert "ERROR: joint 'f1_j1' has inverted limits: lower 1.6 > upper -0.2" in out
    assert "fix: swap lower and upper in the URDF" in out
    assert "NOT usable" in out


def test_a_coupling_past_the_followers_limits_and_a_clamped_close_torque_are_flagged(
    tmp_path, capsys
):
    """q2 = 2 q1 + 0.1 over q1 in [-0.2, 1.6] spans [-0.3, 3.3], past q2's [-0.2, 1.6]; a
    closing torque of 0.1 N*m against a 0.05 N*m limit is clamped."""
    folder = write_toy_hand(
        tmp_path / "toy", tables="[joints]\ntorque_limit = { default = 0.05 }\n", mimic=True
    )
    urdf = folder / "toy.urdf"
    urdf.write_text(urdf.read_text().replace('multiplier="0.8"', 'multiplier="2.0"'))
    assert main(["hand", "check", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "f1_j2  " in out and "follows f1_j1 x 2 + 0.1" in out
    assert (
        "WARNING: joint 'f1_j2' follows 'f1_j1' as 2 x f1_j1 + 0.1, which spans [-0.300, 3.300]"
        in out
    )
    assert "past its own limits [-0.200, 1.600] by 1.700" in out
    assert "[grasping] close_torque of 'f1_j1' is 0.1 N*m, above its torque limit 0.05" in out
    assert "that wholehand does not use" not in out  # hand.toml sets the limits

    # A multiplier rounded in the URDF overshoots by a fraction of a milliradian: no finding.
    # q2 = 1.0005 q1 over q1 in [-0.2, 1.6] spans [-0.2001, 1.6008], 0.8 mrad past q2's limit.
    urdf.write_text(
        urdf.read_text()
        .replace('multiplier="2.0"', 'multiplier="1.0005"')
        .replace('offset="0.1"', 'offset="0"')
    )
    assert main(["hand", "check", str(folder)]) == 0
    assert "past its own limits" not in capsys.readouterr().out


def test_a_broken_hand_toml_is_a_finding_not_a_traceback(tmp_path, capsys):
    folder = write_toy_hand(tmp_path / "toy", 'palm_link = "hand"')
    assert main(["hand", "check", str(folder)]) == 1
    out = capsys.readouterr().out
    assert out.startswith("hand ? from") and "ERROR:" in out and "not valid TOML" in out


def test_a_revolute_joint_without_limit_is_named_with_the_fix(tmp_path):
    from wholehand.errors import AssetError
    from wholehand.models.hand import load_hand

    folder = write_toy_hand(tmp_path / "toy")
    urdf = folder / "toy.urdf"
    text = urdf.read_text()
    start = text.index("<limit")
    urdf.write_text(text[:start] + text[text.index("/>", start) + 2 :])  # the first joint's
    with pytest.raises(AssetError) as err:
        load_hand(folder)
    assert "(revolute) has no <limit>; add <limit lower=" in str(err.value)
    assert "one root link" not in str(err.value)


def test_an_infinite_torque_limit_is_refused_when_the_hand_is_read(tmp_path):
    from wholehand.errors import ConfigError
    from wholehand.models.hand_config import parse_hand_config

    folder = write_toy_hand(tmp_path / "toy", tables="[joints]\ntorque_limit = { default = inf }\n")
    with pytest.raises(ConfigError, match="torque_limit.default must be a finite number, got inf"):
        parse_hand_config(folder)


def test_zero_efforts_and_a_centre_of_mass_far_outside_its_link_are_flagged(tmp_path, capsys):
    """effort="0" silently takes the default torque limit; an <inertial> origin of 0.5 m on a
    finger link (in millimetres meant, say) puts its centre of mass far outside the link and
    asks its joint for m g r = 0.2 kg * 9.81 m/s^2 * 0.5 m ~ 0.98 N*m against 0.2 N*m."""
    folder = write_toy_hand(tmp_path / "toy")
    urdf = folder / "toy.urdf"
    text = urdf.read_text().replace('effort="1"', 'effort="0"')
    start = text.index('<link name="f1_1">')
    at = text.index('<inertial><mass value="0.02"/>', start)
    far = '<inertial><origin xyz="0 0 0.5"/><mass value="0.2"/>'
    urdf.write_text(text[:at] + far + text[at + len('<inertial><mass value="0.02"/>') :])
    assert main(["hand", "check", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "WARNING: 5 joints have effort=\"0\" in toy.urdf: ['f1_j1', 'f1_j2'" in out
    assert "fix: set each motor's effort [N*m] in the URDF" in out
    assert "the centre of mass of ['f1_1'] (0.2 kg) lies 460 mm outside their geometry" in out
    line = next(x for x in out.splitlines() if "needs more torque than the motors" in x)
    assert "at 1 joints [N*m]: f1_j1 0.98" in line and "> 0.2" in line
    # Pinocchio and MuJoCo were compared, and it says how far apart they came out.
    assert "MuJoCo's and Pinocchio's poses of all" in out and "compared at 3 joint" in out
    # Limits set in hand.toml for every joint: the zero efforts no longer matter.
    limits = ", ".join(f"{j} = 0.2" for j in ("f1_j1", "f1_j2", "f2_j1", "f2_j2", "t_j1"))
    folder = write_toy_hand(
        tmp_path / "limited", tables=f"[joints]\ntorque_limit = {{ {limits} }}\n"
    )
    (folder / "toy.urdf").write_text(text)
    assert main(["hand", "check", str(folder)]) == 0
    assert 'effort="0"' not in capsys.readouterr().out


def test_a_spread_motor_gets_no_closing_torque_and_hand_check_says_each_role(tmp_path, capsys):
    """A spread joint at the index's root (about the palm normal) moves the tip sideways: the
    closing torques derived from the model leave it out and close the flexion joints, and
    `hand check` lists the role and the derived closing direction of each joint."""
    from wholehand.models.grasp_styles import derived_close_torque
    from wholehand.models.hand import load_hand
    from wholehand.models.motor_roles import FLEXION, SPREAD, motor_roles

    folder = write_toy_hand(tmp_path / "toy", spread=True)
    hand = load_hand(folder)
    roles = motor_roles(hand)
    assert roles["f1_j0"].role == SPREAD and roles["f1_j0"].angle_deg == pytest.approx(90.0)
    assert roles["f1_j1"].role == roles["f1_j2"].role == FLEXION
    assert roles["t_j1"].finger == "thumb" and roles["t_j1"].role == FLEXION
    derived = derived_close_torque(hand)
    assert "f1_j0" not in derived
    assert all(derived[j] > 0 for j in ("f1_j1", "f1_j2", "f2_j1", "f2_j2", "t_j1"))
    assert main(["hand", "check", str(folder), "--json"]) == 0
    joints = {j["name"]: j for j in json.loads(capsys.readouterr().out)["joints"]}
    assert joints["f1_j0"]["role"] == "spread" and joints["f1_j0"]["derived_close_torque"] is None
    assert joints["f1_j1"]["role"] == "flexion" and joints["f1_j1"]["derived_close_torque"] > 0
    assert main(["hand", "check", str(folder)]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.strip().startswith("f1_j0"))
    assert "index, spread" in line and line.rstrip().endswith("no")


def test_the_shipped_hands_derived_closing_joints_are_their_hand_tomls():
    """On both shipped hands the model alone closes exactly the joints hand.toml closes, each
    the same way: the flexion joints, no spread or thumb-opposition motor."""
    import numpy as np

    from wholehand.models.grasp_styles import derived_close_torque
    from wholehand.models.hand import load_hand

    for name in ("allegro_right", "robotis_hx5_d20_right"):
        hand = load_hand(name)
        shipped = hand.config.grasp_styles["power"].close_torque
        derived = derived_close_torque(hand)
        assert set(derived) == set(shipped), name
        assert all(np.sign(derived[j]) == np.sign(t) for j, t in shipped.items())


def test_hand_check_gives_the_palm_normal_and_flags_a_hand_toml_that_contradicts_it(
    tmp_path, capsys
):
    """The toy hand's fingers close toward +x of its root: hand check says so; a hand.toml
    palm_normal of -x is used but flagged as 180 deg from it."""
    folder = write_toy_hand(tmp_path / "toy")
    assert main(["hand", "check", str(folder), "--json"]) == 0
    palm = json.loads(capsys.readouterr().out)["summary"]["palm_normal"]
    assert palm["model"] == pytest.approx([1.0, 0.0, 0.0], abs=1e-6) and palm["hand_toml"] is None
    flipped = write_toy_hand(tmp_path / "flipped", top="palm_normal = [-1.0, 0.0, 0.0]")
    assert main(["hand", "check", str(flipped)]) == 0
    out = capsys.readouterr().out
    assert "hand.toml gives [-1.0, 0.0, 0.0], 180 deg apart; hand.toml's palm_normal is used" in out
    assert "WARNING: hand.toml's palm_normal is 180 deg from the direction the fingers close" in out


def test_the_picture_draws_each_closing_direction_and_both_palm_normals(tmp_path):
    """On the toy hand (fingers close toward +x of its root) with a contradicting palm_normal
    of -x: the closing fingertips' arrows point toward +x, the model's palm normal is +x and
    hand.toml's -x, both from the palm's middle; the PNG is written."""
    from wholehand.models.hand import load_hand
    from wholehand.models.hand_picture import closing_arrows, plot_samples

    hand = load_hand(write_toy_hand(tmp_path / "flipped", top="palm_normal = [-1.0, 0.0, 0.0]"))
    arrows = closing_arrows(hand)
    tips = [a for a in arrows if a.label != "palm normal"]
    assert sorted(a.label for a in tips) == ["f1_2", "f2_2"]  # the thumb gets no close_torque
    assert all(a.direction[0] > 0.5 for a in tips)
    for a in arrows:
        assert np.linalg.norm(a.direction) == pytest.approx(1.0)
    palms = {a.source: a for a in arrows if a.label == "palm normal"}
    assert palms["model"].direction == pytest.approx([1.0, 0.0, 0.0], abs=1e-6)
    assert palms["hand.toml"].direction == pytest.approx([-1.0, 0.0, 0.0])
    np.testing.assert_array_equal(palms["model"].origin, palms["hand.toml"].origin)
    png = plot_samples(hand, tmp_path / "toy.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
