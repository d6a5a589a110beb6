"""Grasp files and the seeded grasp generator."""

from __future__ import annotations

import json

import numpy as np
import pytest

from wholehand.errors import ConfigError
from wholehand.grasps.generate import generate_grasps
from wholehand.grasps.store import (
    FORMAT,
    Grasp,
    grasp_file,
    load_grasps,
    objects_with_grasps,
    save_grasps,
)
from wholehand.models.object_catalogue import PAPER_OBJECTS, load_object


@pytest.mark.parametrize("name", PAPER_OBJECTS)
def test_ten_power_grasps_ship_for_each_paper_object(allegro, name):
    grasps = load_grasps("allegro_right", name)
    assert len(grasps) >= 10
    for g in grasps:
        assert g.type == "power" and g.contacts >= 3
        q = g.q_array(allegro)
        # MuJoCo's joint limits are soft: pressed fingers sit a few mrad past them.
        assert np.all(q >= allegro.q_lower - 0.01) and np.all(q <= allegro.q_upper + 0.01)
        assert "thumb" in g.extra["fingers"] and len(g.extra["fingers"]) >= 3


def test_generation_is_deterministic_and_reproduces_the_shipped_grasps(allegro):
    cube = load_object("077_rubiks_cube")
    generated, info = generate_grasps(allegro, cube, count=2, seed=0)
    shipped = load_grasps("allegro_right", "077_rubiks_cube")[:2]
    assert info["seed"] == 0
    for g, s in zip(generated, shipped, strict=True):
        np.testing.assert_allclose(g.oMb, s.oMb, atol=1e-8)
        assert g.q == pytest.approx(s.q, abs=1e-8)
        assert g.contacts == s.contacts


def test_round_trip_and_bad_files(tmp_path, allegro):
    grasp = Grasp(0, np.eye(4), dict.fromkeys(allegro.joint_names, 0.3), contacts=4)
    path = save_grasps(tmp_path / "g.json", "allegro_right", "box", [grasp], {"seed": 1})
    (loaded,) = load_grasps(path)
    np.testing.assert_array_equal(loaded.oMb, np.eye(4))
    np.testing.assert_allclose(loaded.q_array(allegro), 0.3)

    raw = json.loads(path.read_text())
    raw["format"] = "other/1"
    path.write_text(json.dumps(raw))
    with pytest.raises(ConfigError, match=FORMAT):
        load_grasps(path)
    raw["format"] = FORMAT
    raw["grasps"][0]["oMb"] = np.ones((4, 4)).tolist()
    path.write_text(json.dumps(raw))
    with pytest.raises(ConfigError, match="oMb"):
        load_grasps(path)
    with pytest.raises(ConfigError, match="no grasp file.*exist for.*077_rubiks_cube"):
        load_grasps("allegro_right", "no_object")
    raw["grasps"][0]["oMb"] = np.eye(4).tolist()
    raw["grasps"][0]["q"] = [0.1] * 16
    path.write_text(json.dumps(raw))
    with pytest.raises(ConfigError, match="grasp 0: q must map joint names to angles"):
        load_grasps(path)
    raw["grasps"][0]["q"] = {"joint_0.0": "up"}
    path.write_text(json.dumps(raw))
    with pytest.raises(ConfigError, match="q\\['joint_0.0'\\] must be a finite angle"):
        load_grasps(path)
    partial = Grasp(0, np.eye(4), {"joint_0.0": 0.0})
    with pytest.raises(ConfigError, match="no angle for joints"):
        partial.q_array(allegro)


def test_a_grasp_with_a_joint_past_its_limit_is_refused_naming_it(tmp_path, allegro, capsys):
    from wholehand.cli.main import main
    from wholehand.grasps.store import LIMIT_SLACK

    i = allegro.model.joints[allegro.model.getJointId("joint_1.0")].idx_q
    upper = allegro.q_upper[i]
    q = dict.fromkeys(allegro.joint_names, 0.3)  # within every joint's limits
    q["joint_1.0"] = upper + 0.9 * LIMIT_SLACK  # a settled grasp's excess: used
    ok = Grasp(0, np.eye(4), q)
    assert ok.q_array(allegro)[i] == q["joint_1.0"]
    q["joint_1.0"] = 5.0
    path = save_grasps(
        tmp_path / "g.json", "allegro_right", "077_rubiks_cube", [Grasp(3, np.eye(4), q)], {}
    )
    (bad,) = load_grasps(path)
    with pytest.raises(ConfigError) as err:
        bad.q_array(allegro)
    message = str(err.value)
    assert str(path) in message and "grasp 3" in message and "'joint_1.0' at 5 rad" in message
    assert f"{upper:.4g}]" in message
    assert main(["run", "--grasps", str(path), "--grasp", "0"]) == 2
    assert "outside its limits" in capsys.readouterr().err


PRECISION_FINGERS = ["index", "middle", "thumb"]


@pytest.mark.parametrize("name", PAPER_OBJECTS)
def test_shipped_precision_grasps_touch_with_three_fingers_only(allegro, name):
    """Every shipped precision grasp, set up in MuJoCo: only index, middle and thumb links touch
    the object (the palm and the ring finger are free), as the generator required."""
    from wholehand import registry
    from wholehand.grasps.store import grasp_file

    if not grasp_file("allegro_right", name, "precision").is_file():
        pytest.skip(f"no precision grasp was found for {name}")
    obj = load_object(name)
    grasps = load_grasps("allegro_right", name, "precision")
    backend = registry.load("backends", "mujoco", hand=allegro, obj=obj)
    allowed = {i for i, f in enumerate(allegro.link_finger) if f in PRECISION_FINGERS}
    for g in grasps:
        assert g.type == "precision" and g.extra["fingers"] == PRECISION_FINGERS
        backend.reset(g.q_array(allegro), g.object_pose(allegro.wMb))
        links = set(backend.ground_truth_contacts().link.tolist())
        assert links <= allowed, [allegro.link_names[i] for i in links - allowed]
        touching = {allegro.link_finger[i] for i in links}
        assert touching == set(PRECISION_FINGERS)


def test_precision_generation_reproduces_the_shipped_grasps(allegro):
    cup = load_object("065-f_cups")
    generated, info = generate_grasps(allegro, cup, count=2, seed=0, style="precision")
    shipped = load_grasps("allegro_right", "065-f_cups", "precision")[:2]
    assert info["command"].endswith("--type precision")
    for g, s in zip(generated, shipped, strict=True):
        np.testing.assert_allclose(g.oMb, s.oMb, atol=1e-8)
        assert g.q == pytest.approx(s.q, abs=1e-8)
        assert g.contacts == s.contacts and g.type == "precision"


def test_unknown_grasp_style_names_the_defined_ones(allegro):
    with pytest.raises(ConfigError, match="no grasp style 'lateral'.*'power', 'precision'"):
        generate_grasps(allegro, load_object("077_rubiks_cube"), count=1, style="lateral")
    with pytest.raises(ConfigError, match="no grasp file.*precision"):
        load_grasps("allegro_right", "no_object", "precision")


def test_objects_with_grasps_lists_the_shipped_files():
    power = objects_with_grasps("allegro_right")
    assert power == sorted(power) and set(PAPER_OBJECTS) <= set(power)
    assert all(grasp_file("allegro_right", name).is_file() for name in power)
    assert objects_with_grasps("allegro_right", "precision") == sorted(PAPER_OBJECTS)
    with pytest.raises(ConfigError, match="no hand named 'no_hand'"):
        objects_with_grasps("no_hand")


def test_generate_all_visits_every_ycb_mesh_and_reports_those_without_grasps(
    tmp_path, monkeypatch, capsys
):
    """``--object all`` runs the generator once per YCB mesh, writes the files that have grasps
    to --out (never the shipped folder then) and names the objects that yield none."""
    import wholehand.grasps.generate as generate
    import wholehand.models.object_catalogue as catalogue
    from wholehand.cli.main import main

    names = ["077_rubiks_cube", "065-f_cups"]
    monkeypatch.setattr(catalogue, "available_objects", lambda: names)
    seen: list[str] = []
    tables: list[bool] = []

    def fake(hand, obj, count, seed, max_candidates, progress, style, on_table, check):
        assert check is None  # no --require-hold
        seen.append(obj.name)
        tables.append(on_table)
        found = [Grasp(0, np.eye(4), dict.fromkeys(hand.joint_names, 0.0))]
        rejected = {"the pre-shape penetrates the object": 2 if obj.name == names[0] else 3}
        info = {"candidates_tried": 3, "seed": seed, "rejected": rejected}
        if on_table:
            info["grasps_per_face"] = [1, 0, 0]
        return (found if obj.name == names[0] else []), info

    monkeypatch.setattr(generate, "generate_grasps", fake)
    assert main(["grasps", "generate", "--object", "all", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert seen == names
    assert [p.name for p in tmp_path.iterdir()] == ["077_rubiks_cube.json"]
    assert "1 of 2 objects yield power grasps" in out and "none for: 065-f_cups" in out
    assert "Rejected because:\n     3  the pre-shape penetrates the object" in out
    assert tables == [False, False]
    args = ["grasps", "generate", "--object", names[0], "--on-table", "--out", str(tmp_path)]
    assert main(args) == 0 and tables[-1] is True
    out = capsys.readouterr().out
    assert "1 grasps from 3 candidates (fewer than --count 10" in out
    assert "on 1 of its 3 resting faces (grasps per face, likeliest first: [1, 0, 0])" in out


def test_a_users_hand_keeps_its_grasps_in_its_own_folder(tmp_path, monkeypatch):
    """Shipped hands read objects/grasps/<name>/; a user's hand folder its grasps/ folder,
    whether its path is written absolute or relative."""
    from toy_hand import write_toy_hand

    from wholehand.grasps.store import grasps_dir, hand_grasps_dir

    assert hand_grasps_dir("allegro_right") == grasps_dir() / "allegro_right"
    folder = write_toy_hand(tmp_path / "hands" / "toy")
    monkeypatch.chdir(tmp_path)
    for written in (folder, "hands/toy", "hands/toy/hand.toml"):
        assert hand_grasps_dir(written) == folder / "grasps"
    assert grasp_file("hands/toy", "box", "precision") == folder / "grasps/precision/box.json"
    grasp = Grasp(0, np.eye(4), {"f1_j1": 0.1}, contacts=3)
    save_grasps(grasp_file("hands/toy", "box"), "toy", "box", [grasp], {})
    assert objects_with_grasps(folder) == ["box"]
    assert load_grasps("hands/toy", "box")[0].q == {"f1_j1": 0.1}


def test_every_rejected_candidate_has_a_reason(allegro):
    """A 30 cm box cannot be grasped by the Allegro: each candidate is rejected with a reason."""
    grasps, info = generate_grasps(allegro, load_object("box:0.3x0.3x0.3"), 1, max_candidates=3)
    assert grasps == [] and info["candidates_tried"] == 3
    assert sum(info["rejected"].values()) == 3
    assert all(isinstance(reason, str) and reason for reason in info["rejected"])


def test_a_penetrating_pre_shape_names_its_deepest_link_and_depth(allegro):
    """A 12 cm cube placed a centimetre or two from the palm meets the open fingers."""
    grasps, info = generate_grasps(allegro, load_object("box:0.12x0.12x0.12"), 1, max_candidates=6)
    named = {r: n for r, n in info["rejected"].items() if r.startswith("the pre-shape penetrates")}
    assert named, info["rejected"]
    depths = info["preshape_depth_mm"]
    for reason in named:
        link = reason.removesuffix(")").split("deepest: ")[1]
        assert link in allegro.link_names and depths[link] > 1.0  # [mm]


def test_a_power_grasp_without_a_thumb_is_refused_with_the_fix(tmp_path):
    from toy_hand import write_toy_hand

    from wholehand.grasps.generate import GraspGenerator
    from wholehand.models.hand import load_hand

    folder = write_toy_hand(tmp_path / "toy")
    toml = folder / "hand.toml"
    toml.write_text(toml.read_text().replace('thumb = "thumb"\n', "", 1))
    hand = load_hand(folder)
    with pytest.raises(ConfigError, match="this hand names no thumb; set thumb ="):
        GraspGenerator(hand, load_object("sphere:0.03"))


def test_any_named_grasp_style_and_its_errors(tmp_path):
    """[grasping.<name>] may be any style; without fingers it is judged like a power grasp."""
    from toy_hand import write_toy_hand

    from wholehand.grasps.generate import GraspGenerator
    from wholehand.models.hand import load_hand

    folder = write_toy_hand(tmp_path / "toy")
    toml = folder / "hand.toml"
    base = toml.read_text()
    top = "\n[grasping.top]\npreshape = { f1_j1 = 0.1 }\nclose_torque = { f1_j1 = 0.1 }\n"
    toml.write_text(base + top)
    hand = load_hand(folder)
    style = hand.config.grasp_styles["top"]
    assert style.fingers == () and style.preshape == {"f1_j1": 0.1}
    assert GraspGenerator(hand, load_object("sphere:0.03"), style="top").style is style
    cases = {
        "\n[grasping.top]\nreach = 1\n": r"unknown keys \['reach'\]",
        "\n[grasping.power]\nclose_torque = { f1_j1 = 0.1 }\n": "name of the main style",
        "\n[grasping.top]\nfingers = ['nope']\n": "must name the thumb",
    }
    for extra, message in cases.items():
        toml.write_text(base + extra)
        with pytest.raises(ConfigError, match=message):
            load_hand(folder)
    toml.write_text(base.replace("[grasping]\n", "[grasping]\nlateral = 1\n", 1))
    with pytest.raises(ConfigError, match="unknown keys \\['lateral'\\] in \\[grasping\\]"):
        load_hand(folder)


def test_a_mesh_path_files_its_grasps_by_its_stem_however_it_is_written(tmp_path, monkeypatch):
    from wholehand.grasps.store import grasp_file

    (tmp_path / "meshes").mkdir()
    monkeypatch.chdir(tmp_path)
    absolute = str(tmp_path / "meshes" / "box.stl")
    by_name = grasp_file("allegro_right", "box")
    assert grasp_file("allegro_right", "meshes/box.stl") == by_name
    assert grasp_file("allegro_right", "./meshes/box.stl") == by_name
    assert grasp_file("allegro_right", absolute) == by_name
    assert grasp_file("allegro_right", "077_rubiks_cube").name == "077_rubiks_cube.json"


def test_a_misspelt_grasp_style_is_named_with_the_styles_there_are():
    from wholehand.errors import ConfigError
    from wholehand.grasps.store import load_grasps

    with pytest.raises(ConfigError, match="no grasp style 'precison' .* did you mean 'precision'"):
        load_grasps("allegro_right", "077_rubiks_cube", "precison")
    with pytest.raises(ConfigError, match="Generate some with .*--type gripper"):
        load_grasps("allegro_right", "077_rubiks_cube", "gripper")  # a new style: generate it
