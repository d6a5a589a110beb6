"""The command line as a user types it."""

from __future__ import annotations

import json

import pytest

from wholehand.cli.main import main


def test_plugins_lists_every_group_with_descriptions(capsys):
    assert main(["plugins"]) == 0
    out = capsys.readouterr().out
    for group in ("contact_estimators", "allocators", "reachers", "backends"):
        assert f"wholehand.{group}:" in out
    assert "mesh_sdf" in out and "Whole-hand contacts" in out
    assert "qp_no_consistency" in out and "mujoco" in out


def test_info_prints_hand_and_object(capsys):
    assert main(["info", "--object", "sphere:0.04"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["hand"]["candidate_points"] > 2000
    assert report["object"]["kind"] == "sphere"


def test_run_prints_stages_and_timings(capsys):
    assert main(["run", "--theta", "0", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["held"] is True
    assert [s["stage"] for s in summary["stages"]][:2] == ["settle", "load +x"]
    assert summary["timing"]["cycles"] == 1300
    assert summary["timing"]["qp_p50_us"] > 0


def test_run_takes_grasp_type_and_backend_options(capsys):
    argv = ["run", "--theta", "0", "--json", "--grasp-type", "precision", "--no-self-collision"]
    assert main(argv) == 0
    spec = json.loads(capsys.readouterr().out)["spec"]
    assert spec["grasp_type"] == "precision"
    assert spec["backend_params"] == {"self_collision": False}


@pytest.mark.parametrize(
    "argv, message",
    [
        (["run", "--estimator", "no_such"], "no plug-in named 'no_such'"),
        (["run", "--object", "077_rubiks_cub"], "077_rubiks_cube"),
        (["info", "--hand", "no_hand"], "no hand named 'no_hand'"),
        (["run", "--grasp", "10"], "grasp 10 does not exist"),
    ],
)
def test_bad_input_exits_with_a_clear_message(capsys, argv, message):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("wholehand: error:") and message in err
