"""The actuation-consistency study: its design over power and precision grasps, and its rows."""

from __future__ import annotations

import numpy as np
import pytest

from wholehand.grasps.store import load_grasps, stored_grasp_indices
from wholehand.models.object_catalogue import PAPER_OBJECTS
from wholehand.studies import get_study, run_study
from wholehand.studies.consistency import METHODS


def _stored(style: str) -> int:
    return sum(len(stored_grasp_indices("allegro_right", o, style, None)) for o in PAPER_OBJECTS)


def test_full_design_covers_every_stored_power_and_precision_grasp():
    jobs = get_study("consistency").jobs("full", seed=0)
    load = [j for j in jobs if j.labels["part"] == "load_test"]
    net = [j for j in jobs if j.labels["part"] == "net_force"]
    n_power, n_precision = _stored("power"), _stored("precision")
    assert n_power == 50 and n_precision > 0
    by_type = {t: sum(j.spec.grasp_type == t for j in load) for t in ("power", "precision")}
    assert by_type == {"power": 2 * n_power, "precision": 2 * n_precision}
    assert len(net) == 2 * n_precision and all(j.kind == "net_force" for j in net)
    assert {j.spec.grasp_type for j in net} == {"precision"}
    for part in (load, net):  # each grasp runs once with and once without the constraint
        pairs: dict[tuple, set[str]] = {}
        for j in part:
            key = (j.spec.object, j.spec.grasp_type, j.spec.grasp)
            pairs.setdefault(key, set()).add(j.labels["method"])
        assert all(methods == set(METHODS) for methods in pairs.values())
    assert all(j.spec.theta_deg == 0.0 for j in jobs)


def test_stored_grasp_indices_keeps_existing_indices_only():
    n = len(load_grasps("allegro_right", "065-f_cups", "precision"))
    assert stored_grasp_indices("allegro_right", "065-f_cups", "precision", None) == list(range(n))
    assert stored_grasp_indices("allegro_right", "065-f_cups", "precision", (0, n, n + 5)) == [0]
    assert stored_grasp_indices("allegro_right", "no_object", "precision", None) == []


def test_tiny_consistency_study_measures_both_grasp_types(tmp_path):
    result = run_study(
        get_study("consistency"), "tiny", tmp_path, executor="serial", progress=False
    )
    summary = result.summary
    cells = {(c["grasp_type"], c["method"]) for c in summary["load_test"]}
    assert cells == {(t, m) for t in ("power", "precision") for m in METHODS}
    net_rows = [r for r in result.rows if r["part"] == "net_force"]
    assert len(net_rows) == len(METHODS)
    for r in net_rows:
        force = np.array([r["net_force_x"], r["net_force_y"], r["net_force_z"]])
        assert r["net_force_N"] == pytest.approx(np.linalg.norm(force), abs=2e-6)
        assert r["net_force_mean_N"] >= 0.0 and r["displacement_mm"] >= 0.0
        assert r["cycles"] == 400  # 2 s at 200 Hz
    by_method = {s["method"]: s for s in summary["net_force"]}
    for r in net_rows:
        assert by_method[r["method"]]["net_force_N_mean"] == pytest.approx(r["net_force_N"])
    assert result.plot_path.stat().st_size > 0
