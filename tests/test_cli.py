"""The command line as a user types it."""

from __future__ import annotations

import json
import re

import numpy as np
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


def test_run_prints_phases_and_timings(capsys):
    assert main(["run", "--theta", "0", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["held"] is True and summary["faults"] == {}
    assert summary["unbalanced_cycles"] == 0
    assert [s["phase"] for s in summary["phases"]][:2] == ["settle", "load +x"]
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
        (["run", "--theta", "nan"], "--theta nan must be a finite angle"),
        (["run", "--theta", "-30"], "--theta -30.0 must be a finite angle"),
        (["run", "--pose-rate", "0"], "--pose-rate 0.0 is invalid"),
        (["run", "--pose-dropout", "1"], "START:DURATION"),
        (["run", "--pose-noise-mm", "inf"], "--pose-noise-mm inf"),
        (["run", "--rate", "1e-3"], "gives no cycle in phase 'settle'"),
        (["run", "--seed", "-1"], "seed must be an integer >= 0, got -1"),
        (["run", "--grasps", "no_such.json"], "no_such.json: cannot read the object"),
        (["reach", "--seed", "-1"], "--seed -1 must be an integer >= 0"),
        (["reach", "--duration", "0"], "--duration 0.0 must be > 0 [s]"),
        (["run", "--sdf-spacing", "fine"], "--sdf-spacing 'fine' must be a spacing in metres"),
        (["run", "--sdf-spacing", "-1"], "sdf_spacing must be > 0 [m] or 'auto', got -1.0"),
        (["run", "--protocol", "dexgraspbench", "--save", "r.npz"], "--save records one run"),
        (["run", "--protocol", "dexgraspbench", "--gravity"], "runs with gravity off"),
    ],
)
def test_bad_input_exits_with_a_clear_message(capsys, argv, message):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("wholehand: error:") and message in err


def test_verbose_goes_before_or_after_the_subcommand(capsys):
    for argv in (["-v", "info"], ["info", "-v"]):
        assert main(argv) == 0
        assert "points_per_link" in json.loads(capsys.readouterr().out)["hand"]
    assert main(["info"]) == 0
    assert "points_per_link" not in json.loads(capsys.readouterr().out)["hand"]


def test_run_finds_a_users_hand_and_its_grasps_by_a_relative_path(tmp_path, monkeypatch, capsys):
    """A hand folder of the user's own (here the Allegro's hand.toml copied) keeps its grasps in
    grasps/ beside hand.toml; ``--grasps FILE`` takes a grasp file from anywhere, its object
    with it."""
    import shutil

    from wholehand.grasps.store import grasp_file
    from wholehand.models.hand_folders import shipped_hands_dir

    folder = tmp_path / "hands" / "mine"
    folder.mkdir(parents=True)
    shutil.copy(shipped_hands_dir() / "allegro_right" / "hand.toml", folder)
    (folder / "grasps").mkdir()
    shutil.copy(grasp_file("allegro_right", "065-f_cups"), folder / "grasps")
    monkeypatch.chdir(tmp_path)
    argv = ["run", "--theta", "0", "--json", "--hand", "hands/mine", "--object", "065-f_cups"]
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out)["held"] is True
    assert (
        main(["run", "--theta", "0", "--json", "--grasps", "hands/mine/grasps/065-f_cups.json"])
        == 0
    )
    spec = json.loads(capsys.readouterr().out)["spec"]
    assert spec["object"] == "065-f_cups"
    assert spec["grasp_file"] == str(folder / "grasps" / "065-f_cups.json")
    argv = ["run", "--grasps", "hands/mine/grasps/065-f_cups.json", "--object", "077_rubiks_cube"]
    assert main(argv) == 2
    assert (
        "holds grasps of '065-f_cups', not of --object '077_rubiks_cube'" in capsys.readouterr().err
    )


def test_run_takes_the_tracking_filters(capsys):
    argv = [
        "run",
        "--theta",
        "0",
        "--json",
        "--pose-rate",
        "30",
        "--pose-latency",
        "0.033",
        "--pose-noise-mm",
        "0.5",
        "--pose-dropout",
        "1.0:0.2",
        "--estimate-at",
        "current",
    ]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["spec"]["tracking"] == {
        "rate_hz": 30.0,
        "latency_s": 0.033,
        "noise_mm": 0.5,
        "noise_seed": 0,
        "dropouts": [[1.0, 0.2]],
    }
    assert summary["spec"]["estimate_at"] == "current"
    assert summary["timing"]["cycles"] == 1300


def test_run_exits_non_zero_when_a_stage_raises(capsys, monkeypatch):
    """A misconfigured plug-in must not look like a string of bad observations."""
    from wholehand_plugins.mesh_sdf import MeshSDFEstimator

    def broken(self, kinematics, wMo, stamp=0.0):
        raise TypeError("estimate() of a broken plug-in")

    monkeypatch.setattr(MeshSDFEstimator, "estimate", broken)
    assert main(["run", "--theta", "0"]) == 1
    captured = capsys.readouterr()
    # Zero torque from the start: the grasp is lost, and every cycle until then raised.
    count = re.search(r"stage 'regulate' raised (\d+) times", captured.err)
    assert count and int(count.group(1)) > 100
    assert "TypeError: estimate() of a broken plug-in" in captured.err
    assert f"{count.group(1)} stage_error" in captured.out


def test_run_takes_the_dexgraspbench_protocol(capsys):
    # Feedforward on the cube's grasp 0 turns it 15 deg while closing: one direction, quickly.
    argv = ["run", "--protocol", "dexgraspbench", "--allocator", "feedforward"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "DexGraspBench load test: allegro_right, 077_rubiks_cube grasp 0, feedforward" in out
    assert "  +x         no" in out and "settle" in out and "held: no" in out


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "--object", ""],
        ["info", "--hand", " "],
        ["grasps", "generate", "--object", ""],
        ["bench", "cycle", "--object", ""],
        ["control", "--config", ""],
        ["hand", "check", ""],
    ],
)
def test_an_empty_value_is_refused_not_replaced_by_a_default(argv, capsys):
    from wholehand.cli.main import main

    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    assert "is empty; give a value or leave it out" in capsys.readouterr().err


@pytest.mark.parametrize("kind", ["truncated", "text", "pickled", "missing"])
def test_view_names_a_file_that_is_not_a_run_record(kind, tmp_path, capsys):
    from wholehand.cli.main import main

    path = tmp_path / "run.npz"
    if kind == "truncated":
        np.savez(path, phases=np.array(["settle"]), meta=np.array("{}"), q=np.zeros((50, 16)))
        path.write_bytes(path.read_bytes()[:300])
    elif kind == "text":
        path.write_text("not a record\n")
    elif kind == "pickled":
        np.save(path, np.array([{"a": 1}], dtype=object), allow_pickle=True)
        path = path.with_name("run.npz.npy")
    assert main(["view", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "Traceback" not in err
    assert {"truncated": "truncated", "text": "not a", "pickled": "not a run record",
            "missing": "no run record at"}[kind] in err  # fmt: skip


def test_a_reader_that_leaves_early_gets_no_traceback():
    """`wholehand objects | head -1`: the pipe closes before the list is written."""
    import subprocess
    import sys

    script = (
        "import os, sys\n"
        "r, w = os.pipe(); os.close(r); os.dup2(w, 1)\n"  # a pipe nobody reads
        "from wholehand.cli.main import main\n"
        "sys.stderr.write(f'rc={main([\"objects\"])}\\n')\n"
    )
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and "rc=0" in run.stderr, run.stderr
    assert "Traceback" not in run.stderr and "BrokenPipeError" not in run.stderr, run.stderr


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["hw-sim", "--settle", "-1"], "argument --settle: -1 is not a time > 0 [s]"),
        (["control", "--duration", "-1"], "argument --duration: -1 is not a time > 0 [s]"),
        (["control", "--qp-deadline", "nan"], "argument --qp-deadline: nan is not a time >= 0"),
        (["hw-sim", "--wait", "0"], "argument --wait: 0 is not a time > 0 [s]"),
        (["grasps", "generate", "--object", "x", "--count", "0"], "--count: 0 is not a whole"),
        (["grasps", "generate", "--object", "x", "--count", "-2"], "--count: -2 is not a whole"),
        (["grasps", "generate", "--object", "x", "--seed", "-1"], "--seed: -1 is not a whole"),
        (["grasps", "generate", "--object", "x", "--max-candidates", "-3"], "-3 is not a whole"),
        (["grasps", "generate", "--object", "x", "--count", "two"], "'two' is not a whole"),
    ],
)
def test_numbers_are_checked_before_anything_starts(argv, message, capsys):
    """Times, counts and seeds are checked when the command line is parsed: before a
    controller joins the network or a generator builds a model."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err
