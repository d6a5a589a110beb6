"""Studies framework: job expansion, statistics, determinism across executors, CLI wiring."""

from __future__ import annotations

import argparse
import csv
import json

import numpy as np
import pytest

from wholehand.errors import ConfigError
from wholehand.loop.record import STATUS_CODES, RunRecord
from wholehand.studies import STUDIES, TIMING_COLUMNS, get_study, run_study
from wholehand.studies.base import derive_seed, success_stats
from wholehand.studies.executors import execute
from wholehand.studies.runner import record_row


def _read(path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_full_designs_match_the_paper():
    pert = get_study("perturbation").jobs("full", seed=0)
    # 5 objects x 10 grasps, 4 methods: 1 trial at 0 deg + 10 random axes at 30, 60, 90 deg.
    assert len(pert) == 50 * 4 * (1 + 3 * 10)
    assert {j.labels["method"] for j in pert} == {
        "qp",
        "fingertip_only",
        "feedforward",
        "impedance",
    }
    ks = get_study("k-sweep").jobs("full", seed=0)
    per_k = {k: sum(j.labels["k"] == k for j in ks) for k in (1, 3, 5, 7)}
    assert per_k == {1: 750, 3: 750, 5: 750, 7: 750}  # paper Fig. 7: 750 attempts per K
    assert {j.spec.estimator_params["k"] for j in ks} == {1, 3, 5, 7}
    assert len(get_study("contacts").jobs("full", seed=0)) == 50 * 4
    assert [j.index for j in pert] == list(range(len(pert)))


def test_seeds_are_paired_across_methods_and_follow_the_study_seed():
    jobs = get_study("perturbation").jobs("quick", seed=0)
    by_key: dict[tuple, set[int]] = {}
    for j in jobs:
        key = (j.spec.object, j.spec.grasp, j.spec.theta_deg, j.labels["repeat"])
        by_key.setdefault(key, set()).add(j.spec.seed)
    assert all(len(s) == 1 for s in by_key.values())  # same pull axis for every method
    assert len({next(iter(s)) for s in by_key.values()}) > 1
    again = get_study("perturbation").jobs("quick", seed=0)
    other = get_study("perturbation").jobs("quick", seed=1)
    assert [j.spec for j in again] == [j.spec for j in jobs]
    assert [j.spec.seed for j in other] != [j.spec.seed for j in jobs]
    assert derive_seed(0, 1, 2, 3) == derive_seed(0, 1, 2, 3) != derive_seed(0, 1, 2, 4)


def test_success_stats_by_hand():
    rows = [
        {"hand": "h", "object": "a", "grasp": 0, "held": True},
        {"hand": "h", "object": "a", "grasp": 0, "held": True},
        {"hand": "h", "object": "a", "grasp": 1, "held": True},
        {"hand": "h", "object": "a", "grasp": 1, "held": False},
        {"hand": "h", "object": "b", "grasp": 0, "held": False},
    ]
    stats = success_stats(rows)
    # grasp-level rates 1, 0.5, 0: mean 0.5, sample std 0.5, SE 0.5 / sqrt(3)
    assert stats["success"] == pytest.approx(0.5)
    assert stats["se"] == pytest.approx(0.5 / np.sqrt(3))
    assert (stats["n_grasps"], stats["n_trials"]) == (3, 5)
    assert success_stats(rows[:1])["se"] == 0.0


def test_record_row_names_the_failure_stage():
    record = RunRecord(stages=["settle", "load +x", "load -x"])
    extra = {k: np.zeros(2) for k in RunRecord.FIELDS}  # fields this test does not look at
    extra.update({k: np.zeros((0, 3)) for k in getattr(RunRecord, "CONTACT_FIELDS", ())})
    extra["contact_link"] = np.zeros(0, dtype=int)
    for i, (stage, held) in enumerate([(0, True), (1, True), (1, False)]):
        values = {
            **extra, "t": 0.005 * i, "stage": stage, "n_contacts": 4 + i,
            "residual_wrench": np.zeros(6), "tau": np.zeros(2), "qp_time": 1e-4,
            "estimate_time": 1e-4, "cycle_time": 2e-3,
            "status": STATUS_CODES[next(iter(STATUS_CODES))], "held": held,
            "p_object": np.array([0.0, 0.0, 0.001 * i]), "r_object": np.zeros(3),
        }  # fmt: skip
        record.append(**values)
    row = record_row(record)
    assert row["held"] is False and row["failure_stage"] == "load +x"
    assert row["stages_reached"] == 2 and row["stages_total"] == 3
    assert row["contacts_mean"] == pytest.approx(5.0)
    assert row["final_displacement_mm"] == pytest.approx(2.0)
    assert row["control_rate_hz"] == pytest.approx(500.0)


def test_bad_names_raise():
    with pytest.raises(ConfigError, match="available"):
        get_study("nope")
    with pytest.raises(ConfigError, match="size"):
        get_study("perturbation").jobs("huge", seed=0)
    with pytest.raises(ConfigError, match="executor"):
        execute([], dict, executor="dask")
    with pytest.raises(ConfigError, match="workers"):
        execute([], dict, workers=0)


def test_cli_parser_registers_study():
    from wholehand.cli import study

    parser = argparse.ArgumentParser()
    study.add_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["study", "k-sweep", "--quick", "--workers", "2", "--seed", "3"])
    assert (args.name, args.quick, args.workers, args.seed) == ("k-sweep", True, 2, 3)
    assert args.executor == "process" and args.func is study._cmd_study
    assert set(STUDIES) >= {"perturbation", "k-sweep", "consistency", "contacts"}


def test_tiny_study_is_deterministic_across_executors(tmp_path):
    """Smoke test: the tiny perturbation study, serial and in a 2-process pool, same rows."""
    study = get_study("perturbation")
    serial = run_study(study, "tiny", tmp_path / "serial", executor="serial", progress=False)
    pooled = run_study(
        study, "tiny", tmp_path / "pool", executor="process", workers=2, progress=False
    )
    a, b = _read(serial.csv_path), _read(pooled.csv_path)
    assert len(a) == len(study.jobs("tiny", 0)) == 4
    assert [r["index"] for r in a] == ["0", "1", "2", "3"]
    assert list(a[0])[-len(TIMING_COLUMNS) :] == list(TIMING_COLUMNS)
    strip = lambda rows: [{k: v for k, v in r.items() if k not in TIMING_COLUMNS} for r in rows]  # noqa: E731
    assert strip(a) == strip(b)
    assert all(r["error"] == "" for r in a)
    assert {r["method"] for r in a} == {"qp", "feedforward"}
    assert all(int(r["n_contacts_gt_init"]) > 0 for r in a)
    summary = json.loads(serial.summary_path.read_text())
    assert summary["n_trials"] == 4 and summary["n_errors"] == 0
    assert {(g["method"], g["theta_deg"]) for g in summary["groups"]} == {
        ("qp", 0.0), ("qp", 60.0), ("feedforward", 0.0), ("feedforward", 60.0),
    }  # fmt: skip
    assert serial.plot_path.stat().st_size > 1000
    assert serial.plot_path.read_bytes()[:4] == b"\x89PNG"


def test_ray_executor_gives_the_serial_rows(tmp_path):
    """The tiny study on a local Ray instance (2 CPUs) writes the same rows as the serial run."""
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'wholehand[ray]')")
    study = get_study("perturbation")
    serial = run_study(study, "tiny", tmp_path / "serial", executor="serial", progress=False)
    on_ray = run_study(study, "tiny", tmp_path / "ray", executor="ray", workers=2, progress=False)
    strip = lambda rows: [{k: v for k, v in r.items() if k not in TIMING_COLUMNS} for r in rows]  # noqa: E731
    assert strip(_read(on_ray.csv_path)) == strip(_read(serial.csv_path))
    assert json.loads(on_ray.summary_path.read_text())["executor"] == "ray"


def test_success_stats_leave_out_errored_and_diverged_trials():
    row = {"hand": "h", "object": "o", "held": True, "error": ""}
    rows = [
        {**row, "grasp": 0},
        {**row, "grasp": 0, "held": False},
        {**row, "grasp": 1},
        {**row, "grasp": 1, "held": False, "error": "simulation diverged (MuJoCo bad_qacc x1)"},
    ]
    stats = success_stats(rows)
    assert stats["success"] == pytest.approx(0.75)  # grasp 0: 1/2, grasp 1: 1/1
    assert stats["n_trials"] == 3 and stats["n_excluded"] == 1
