"""Every example runs in its quick mode and prints what it promises."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def _run(name: str, *args: str) -> str:
    done = subprocess.run(
        [sys.executable, str(EXAMPLES / name), "--quick", *args],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def test_every_example_is_tested():
    tested = {
        "compare_methods.py",
        "tracking_noise_estimator.py",
        "contacts_per_link.py",
        "tracking_latency.py",
        "feedforward_pose_error.py",
        "criteria_by_hand.py",
    }
    assert {p.name for p in EXAMPLES.glob("*.py")} == tested


def test_examples_use_the_public_names_only():
    """An example is what a user copies: it imports from ``wholehand`` itself, not from its
    modules or the plug-ins."""
    for path in EXAMPLES.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                top = node.module.split(".")[0]
                if top.startswith("wholehand"):
                    assert node.module == "wholehand", f"{path.name}: from {node.module} import"
            elif isinstance(node, ast.Import):
                assert not any(a.name.startswith("wholehand") for a in node.names), path.name


def test_compare_methods_reports_every_method():
    out = _run("compare_methods.py", "--object", "077_rubiks_cube")
    for method in ("qp", "fingertip_only", "feedforward", "impedance"):
        assert f"\n{method} " in out


def test_tracking_noise_estimator_runs_four_noise_levels():
    out = _run("tracking_noise_estimator.py")
    rows = [line for line in out.splitlines()[2:] if line.strip()]
    assert len(rows) == 4 and all(r.split()[2] in ("yes", "no") for r in rows)


@pytest.mark.parametrize("grasp_type", ["power", "precision"])
def test_contacts_per_link_lists_links_and_writes_html(tmp_path, grasp_type):
    html = tmp_path / "run.html"
    out = _run("contacts_per_link.py", "--grasp-type", grasp_type, "--html", str(html))
    assert "fingertip" in out and html.stat().st_size > 10_000
    if grasp_type == "power":
        assert "palm_link" in out  # a power grasp of the cube rests on the palm


def test_tracking_latency_compares_three_conditions():
    out = _run("tracking_latency.py")
    rows = {line.split()[0]: line.split() for line in out.splitlines()[2:] if line.strip()}
    assert set(rows) == {"exact", "object_stamp", "current"}
    assert all(0.0 <= float(r[1]) <= 100.0 for r in rows.values())


def test_feedforward_pose_error_compares_the_torques_with_and_without_the_error():
    out = _run("feedforward_pose_error.py")
    row = out.splitlines()[1].split()
    assert row[:2] == ["077_rubiks_cube", "0"]
    cosine, change, flips = float(row[2]), float(row[3]), int(row[4])
    assert -1.0 <= cosine < 1.0 and change > 0.0 and flips >= 0  # the error moves the torques
    assert "cosine median" in out.splitlines()[-1]


def test_criteria_by_hand_prints_the_stored_runs_rates(tmp_path):
    """Each printed row carries the rates the study's own summary.json recorded for that run,
    method and angle, and the plot is written."""
    import json

    png = tmp_path / "criteria.png"
    out = _run("criteria_by_hand.py", "--png", str(png))
    printed = {}
    for line in out.splitlines()[1:]:
        f = line.split()
        if len(f) == 10 and f[4] == "+-":
            printed[(f[0], f[1], float(f[2]))] = (float(f[3]), float(f[6]), int(f[9]))
    data = EXAMPLES.parent / "docs" / "data"
    expected = {}
    for folder, label in (("perturbation-strict", "Allegro"), ("unseen-hands/inspire", "Inspire")):
        for g in json.loads((data / folder / "summary.json").read_text())["groups"]:
            key = (label, g["method"], float(g["theta_deg"]))
            expected[key] = (100 * g["success"], 100 * g["success_strict"], g["n_grasps"])
    for key, (paper, strict, grasps) in expected.items():
        assert printed[key][0] == pytest.approx(paper, abs=0.051)
        assert printed[key][1] == pytest.approx(strict, abs=0.051)
        assert printed[key][2] == grasps
    assert png.stat().st_size > 10_000
