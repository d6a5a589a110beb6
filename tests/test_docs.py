"""docs/adding_a_hand.md, followed as a user would: its hand.toml and every command in it."""

from __future__ import annotations

import json
import re
import shlex
import shutil
from pathlib import Path

from wholehand.cli.main import main
from wholehand.models.hand_folders import shipped_hands_dir

DOC = Path(__file__).resolve().parents[1] / "docs" / "adding_a_hand.md"


def _blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", DOC.read_text(), flags=re.S)


def test_adding_a_hand_from_its_urdf_to_a_held_grasp_and_a_study(tmp_path, monkeypatch, capsys):
    folder = tmp_path / "my_hands" / "hx5"
    folder.mkdir(parents=True)
    shipped = shipped_hands_dir() / "robotis_hx5_d20_right"
    shutil.copy(shipped / "hx5_d20_right.urdf", folder)
    shutil.copytree(shipped / "meshes", folder / "meshes")
    (folder / "hand.toml").write_text(_blocks("toml")[0])  # the page's hand.toml, as written
    monkeypatch.chdir(tmp_path)
    commands = [line for block in _blocks("bash") for line in block.splitlines() if line]
    assert len(commands) == 7
    for command in commands:
        words = shlex.split(command)
        assert words[0] == "wholehand"
        assert main(words[1:]) == 0, command
    out = capsys.readouterr().out
    assert "usable" in out and "NOT usable" not in out
    assert (folder / "samples.png").is_file()
    assert "result: HELD through every phase" in out
    assert re.search(r"\d of 3 grasps pass", out)  # the reach check of the 3 stored grasps
    grasps = json.loads((folder / "grasps" / "077_rubiks_cube.json").read_text())
    assert len(grasps["grasps"]) == 3
    optimized = json.loads((folder / "optimized" / "077_rubiks_cube.json").read_text())
    assert (
        len(optimized["grasps"]) == 2 and "--method optimize" in optimized["generator"]["command"]
    )
    held = json.loads((folder / "held" / "077_rubiks_cube.json").read_text())
    assert len(held["grasps"]) == 1 and "--require-hold 60" in held["generator"]["command"]
    summary = json.loads((folder / "study" / "summary.json").read_text())
    assert {g["method"] for g in summary["groups"]} == {"qp", "feedforward"}
    assert summary["n_trials"] == 4


def test_the_reference_hand_toml_names_every_key_the_parser_knows():
    from wholehand.models import hand_config

    reference = _blocks("toml")[-1]
    assert "palm_link" in hand_config.HAND_KEYS
    for key in hand_config.HAND_KEYS:
        assert re.search(rf"^\[?{key}\b", reference, flags=re.M), key


def test_the_arm_assembly_of_the_page_loads_and_checks(tmp_path, monkeypatch, capsys):
    from wholehand.models.hand import load_hand

    shipped = shipped_hands_dir()
    hand = tmp_path / "my_hands" / "hx5"
    hand.mkdir(parents=True)
    shutil.copy(shipped / "robotis_hx5_d20_right" / "hx5_d20_right.urdf", hand)
    shutil.copytree(shipped / "robotis_hx5_d20_right" / "meshes", hand / "meshes")
    (hand / "hand.toml").write_text(_blocks("toml")[0])
    arm = tmp_path / "my_arm"
    shutil.copytree(shipped / "flexiv_rizon4", arm)
    (arm / "rizon4.urdf").rename(arm / "arm.urdf")
    rig = tmp_path / "my_arm_my_hand"
    rig.mkdir()
    (rig / "hand.toml").write_text(_blocks("toml")[1])
    monkeypatch.chdir(tmp_path)
    model = load_hand("my_arm_my_hand")
    assert int(model.arm_dofs.sum()) == 7 and model.nq == 27
    assert main(["hand", "check", "my_arm_my_hand"]) == 0
    out = capsys.readouterr().out
    assert out.count("arm (position)") == 7 and "NOT usable" not in out
