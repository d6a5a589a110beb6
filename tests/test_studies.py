"""Studies framework: job expansion, statistics, determinism across executors, CLI wiring."""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import operator
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from wholehand.errors import ConfigError, PluginError
from wholehand.grasps.store import load_grasps, objects_with_grasps
from wholehand.loop.record import RunRecord
from wholehand.models.object_catalogue import PAPER_OBJECTS
from wholehand.studies import STUDIES, TIMING_COLUMNS, get_study, run_study, runner
from wholehand.studies.base import derive_seed, success_stats
from wholehand.studies.executors import execute
from wholehand.studies.resume import execution_order, match_rows
from wholehand.studies.rows import SPEC_COLUMNS, record_row, spec_columns
from wholehand.studies.study_files import JOURNAL_NAME, read_csv, read_journal, write_csv


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
    contacts = get_study("contacts").jobs("full", seed=0)
    # Every object with shipped power grasps, every stored grasp, the four methods.
    objects = objects_with_grasps("allegro_right")
    n_grasps = sum(len(load_grasps("allegro_right", o)) for o in objects)
    assert set(PAPER_OBJECTS) <= {j.spec.object for j in contacts} == set(objects)
    assert len(contacts) == 4 * n_grasps
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
    record = RunRecord(phases=["settle", "load +x", "load -x"])
    extra = {k: np.zeros(2) for k in RunRecord.FIELDS}  # fields this test does not look at
    extra.update({k: np.zeros((0, 3)) for k in getattr(RunRecord, "CONTACT_FIELDS", ())})
    extra["contact_link"] = np.zeros(0, dtype=int)
    for i, (stage, held) in enumerate([(0, True), (1, True), (1, False)]):
        values = {
            **extra,
            "t": 0.005 * i,
            "stamp_object": 0.005 * i,
            "phase": stage,
            "stage": "regulate",
            "n_contacts": 4 + i,
            "residual_wrench": np.zeros(6),
            "tau": np.zeros(2),
            "qp_time": 1e-4,
            "estimate_time": 1e-4,
            "cycle_time": 2e-3,
            "status": "ok",
            "held": held,
            "p_object": np.array([0.0, 0.0, 0.001 * i]),
            "r_object": np.zeros(3),
        }
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
    with pytest.raises(ConfigError, match="limit must be >= 0"):
        run_study(get_study("perturbation"), "tiny", limit=-1)


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
        ("qp", 0.0),
        ("qp", 60.0),
        ("feedforward", 0.0),
        ("feedforward", 60.0),
    }
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
    # Diverged counted as lost: grasp 1 holds 1 of 2; a trial that raised stays out.
    raised = {**row, "grasp": 2, "error": "ValueError: bad spec"}
    stats = success_stats([*rows, raised])
    assert stats["success_diverged_lost"] == pytest.approx(0.5)
    assert (stats["n_diverged"], stats["n_excluded"], stats["n_grasps"]) == (1, 2, 2)


# --- Long runs: journal, resume, limit, partial outputs ---------------------------------------


def _strip(rows):
    """Rows without their timing columns, NaN as a string (NaN != NaN)."""
    nan = lambda v: "nan" if isinstance(v, float) and v != v else v  # noqa: E731
    return [{k: nan(v) for k, v in r.items() if k not in TIMING_COLUMNS} for r in rows]


def _journal_lines(folder):
    return (folder / JOURNAL_NAME).read_text().splitlines()


@pytest.fixture(scope="module")
def tiny_fresh(tmp_path_factory):
    """The tiny perturbation study run once, complete, serially (4 trials)."""
    folder = tmp_path_factory.mktemp("fresh")
    return run_study(get_study("perturbation"), "tiny", folder, executor="serial", progress=False)


def test_read_csv_inverts_write_csv(tiny_fresh, tmp_path):
    """Values and types of a tiny study's rows survive trials.csv; cells are typed as written."""
    back = read_csv(tiny_fresh.csv_path)
    typed = lambda rows: [{k: (type(v).__name__, v) for k, v in r.items()} for r in _strip(rows)]  # noqa: E731
    assert typed(back) == typed(tiny_fresh.rows)
    spec = spec_columns(get_study("perturbation").jobs("tiny", 0)[0].spec)
    assert back[0]["protocol_params"] == spec["protocol_params"]  # JSON text, as written
    cells = {
        "n": "077",
        "u": "1_000",
        "f": "-0.5",
        "e": "1e-05",
        "x": "nan",
        "i": "-inf",
        "b": "True",
        "z": "",
        "s": "qp",
        "error": "",
        "k": "7",
    }
    row = read_csv(write_csv([cells], tmp_path / "cells.csv"))[0]
    assert row == {
        **row,
        "n": "077",
        "u": "1_000",
        "f": -0.5,
        "e": 1e-05,
        "i": -float("inf"),
        "b": True,
        "z": None,
        "s": "qp",
        "error": "",
        "k": 7,
    }
    assert isinstance(row["x"], float) and row["x"] != row["x"]


def test_run_trials_gives_the_rows_of_a_study(tiny_fresh):
    """``wholehand.run_trials`` on a study's specs: the study's rows without its labels."""
    import wholehand

    specs = [job.spec for job in get_study("perturbation").jobs("tiny", 0)[:2]]
    rows = wholehand.run_trials(specs, executor="serial")
    for row, study_row in zip(rows, tiny_fresh.rows[:2], strict=True):
        same = [k for k in row if k not in TIMING_COLUMNS and k not in ("index", "kind")]
        assert {k: row[k] for k in same} == {k: study_row[k] for k in same}


def test_limit_then_resume_gives_the_rows_of_a_complete_run(tmp_path, tiny_fresh, capsys):
    study = get_study("perturbation")
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / JOURNAL_NAME).write_text('{"stale": "row of an earlier run"}\n')
    first = run_study(study, "tiny", folder, executor="serial", progress=False, limit=1)
    # Without --resume the old journal is replaced; each finished row is one line at once.
    lines = _journal_lines(folder)
    assert len(lines) == 1 and json.loads(lines[0])["index"] == 0
    assert not first.complete and len(first.rows) == 1
    summary = json.loads(first.summary_path.read_text())
    assert (summary["complete"], summary["n_planned"], summary["n_trials"]) == (False, 4, 1)
    assert len(read_csv(first.csv_path)) == 1 and first.plot_path.stat().st_size > 1000
    err = capsys.readouterr().err
    assert f"wholehand study perturbation --out {folder} --resume --size tiny" in err
    second = run_study(study, "tiny", folder, executor="serial", progress=False, resume=True)
    assert second.complete and second.summary["n_reused"] == 1
    assert json.loads(second.summary_path.read_text())["complete"] is True
    assert _strip(second.rows) == _strip(tiny_fresh.rows)
    assert _strip(read_csv(second.csv_path)) == _strip(read_csv(tiny_fresh.csv_path))
    assert len(_journal_lines(folder)) == 4
    assert "1 of 4 trials reused" in capsys.readouterr().err


def test_interrupted_run_writes_a_balanced_partial_result(tmp_path, monkeypatch, capsys):
    """KeyboardInterrupt after 5 trials of the full design (fake trials): outputs of the 5,
    every one a repeat 0, and the command to continue."""
    ran: list[int] = []

    def fake_trial(job):
        if len(ran) == 5:
            raise KeyboardInterrupt
        ran.append(job.index)
        return {"held": True, "stages_total": 1, "failure_stage": "", "error": "", "cycles": 1}

    monkeypatch.setitem(runner.JOB_KINDS, "trial", fake_trial)
    monkeypatch.setattr(runner, "_warm_caches", lambda jobs: None)
    study = get_study("perturbation")
    result = run_study(study, "full", tmp_path, executor="serial", progress=False)
    jobs = study.jobs("full", 0)
    assert result.interrupted and not result.complete
    assert ran == [j.index for j in execution_order(jobs)[:5]]
    assert all(jobs[i].labels["repeat"] == 0 for i in ran)
    assert [r["index"] for r in read_csv(result.csv_path)] == sorted(ran)
    summary = json.loads(result.summary_path.read_text())
    assert (summary["complete"], summary["n_planned"], summary["n_trials"]) == (False, 6200, 5)
    assert len(_journal_lines(tmp_path)) == 5
    err = capsys.readouterr().err
    assert (
        "interrupted" in err and f"wholehand study perturbation --out {tmp_path} --resume\n" in err
    )
    order = execution_order(get_study("k-sweep").jobs("full", 0))
    first_repeat_1 = [j.labels["repeat"] for j in order].index(1)
    assert first_repeat_1 == len(order) // 5  # every (object, grasp, theta, K) once first


def _sigterm_after_three_trials(monkeypatch) -> None:
    """Trials that finish at once, with a SIGTERM to this process as the fourth starts."""
    ran: list[int] = []

    def fake_trial(job):
        if len(ran) == 3:
            os.kill(os.getpid(), signal.SIGTERM)
        ran.append(job.index)
        return {"held": True, "stages_total": 1, "failure_stage": "", "error": "", "cycles": 1}

    monkeypatch.setitem(runner.JOB_KINDS, "trial", fake_trial)
    monkeypatch.setattr(runner, "_warm_caches", lambda jobs: None)


def test_sigterm_ends_a_run_like_ctrl_c(tmp_path, monkeypatch, capsys):
    """SIGTERM (a scheduler stopping the job) writes the finished rows and says how to go on;
    the previous SIGTERM handler is back afterwards."""
    _sigterm_after_three_trials(monkeypatch)
    before = signal.getsignal(signal.SIGTERM)
    result = run_study(
        get_study("perturbation"), "full", tmp_path, executor="serial", progress=False
    )
    assert result.interrupted and len(read_csv(result.csv_path)) == 3
    assert "--resume" in capsys.readouterr().err
    assert signal.getsignal(signal.SIGTERM) is before


def test_a_second_sigterm_while_stopping_does_not_break_off_the_writes(tmp_path, monkeypatch):
    """A scheduler that sends SIGTERM twice: the second arrives while the finished rows are
    being written, and is ignored."""
    _sigterm_after_three_trials(monkeypatch)
    write = runner.write_csv

    def write_after_a_second_sigterm(rows, path):
        os.kill(os.getpid(), signal.SIGTERM)
        return write(rows, path)

    monkeypatch.setattr(runner, "write_csv", write_after_a_second_sigterm)
    result = run_study(
        get_study("perturbation"), "full", tmp_path, executor="serial", progress=False
    )
    assert result.interrupted and len(read_csv(result.csv_path)) == 3
    assert (tmp_path / "summary.json").is_file()


OLDER_COLUMNS = ("kind", "pose_error", "grasp_type", "balance_weight")
"""Columns that rows of older versions lack."""


def test_resume_from_trials_csv_of_an_older_version(tmp_path, tiny_fresh):
    """A folder holding only trials.csv, without the columns newer versions added, continues."""
    old = [{k: v for k, v in r.items() if k not in OLDER_COLUMNS} for r in tiny_fresh.rows]
    write_csv(old, tmp_path / "trials.csv")
    result = run_study(
        get_study("perturbation"),
        "tiny",
        tmp_path,
        executor="serial",
        progress=False,
        resume=True,
        limit=0,
    )
    assert result.complete and result.summary["n_reused"] == 4
    assert _strip(result.rows) == _strip(tiny_fresh.rows)  # the missing cells read as defaults
    assert len(_journal_lines(tmp_path)) == 4  # the reused rows are journaled too


def test_resume_from_trials_csv_mixing_older_and_newer_rows(tmp_path, tiny_fresh):
    """Older rows (without the OLDER_COLUMNS) and newer rows in one trials.csv: the older ones
    get empty cells in the newer columns, and still match."""
    old = [{k: v for k, v in r.items() if k not in OLDER_COLUMNS} for r in tiny_fresh.rows]
    write_csv([*old[:2], *tiny_fresh.rows[2:]], tmp_path / "trials.csv")
    assert read_csv(tmp_path / "trials.csv")[0]["pose_error"] == ""
    result = run_study(
        get_study("perturbation"),
        "tiny",
        tmp_path,
        executor="serial",
        progress=False,
        resume=True,
        limit=0,
    )
    assert result.complete and result.summary["n_reused"] == 4
    # The empty cells are filled, so every trial counts for its own grasp in the summary.
    assert _strip(result.rows) == _strip(tiny_fresh.rows)
    assert result.summary["groups"] == tiny_fresh.summary["groups"]


def test_resume_reruns_rows_without_a_result_and_names_a_cut_line(tmp_path, tiny_fresh, capsys):
    """A trials.csv whose ``held`` column was removed by hand, and one whose last line was cut:
    those rows are damaged, said so, and their trials run again."""
    no_held = [{k: v for k, v in r.items() if k != "held"} for r in tiny_fresh.rows]
    write_csv(no_held, tmp_path / "trials.csv")
    kwargs = {"executor": "serial", "progress": False, "resume": True, "limit": 0}
    result = run_study(get_study("perturbation"), "tiny", tmp_path, **kwargs)
    assert result.summary["n_reused"] == 0 and not result.complete
    assert "4 damaged rows (no result) re-run" in capsys.readouterr().err
    assert _journal_lines(tmp_path) == []  # nothing damaged is journaled
    folder = tmp_path / "cut"
    folder.mkdir()
    path = write_csv(tiny_fresh.rows, folder / "trials.csv")
    text = path.read_text().rstrip("\n")
    cut = text[: text.rindex(",")] + "\n"  # the last line lost its last cell
    path.write_text(cut)
    (tmp_path / "cut.csv").write_text(cut)
    result = run_study(get_study("perturbation"), "tiny", folder, **kwargs)
    err = capsys.readouterr().err
    assert result.summary["n_reused"] == 3
    assert "1 damaged rows (no result) re-run (trials.csv lines cut short: [5])" in err
    assert "0 rows matching no job" in err
    with pytest.raises(ConfigError, match="line 5: fewer cells than the header"):
        read_csv(tmp_path / "cut.csv")


def test_resume_reruns_trials_that_raised_and_keeps_diverged_ones(tmp_path, tiny_fresh):
    rows = [dict(r) for r in tiny_fresh.rows]
    outcome = set(rows[1]) - set(SPEC_COLUMNS) - {"index", "kind", "method", "repeat"}
    failed = {k: v for k, v in rows[1].items() if k not in outcome}
    rows[1] = {**failed, "held": False, "failure_stage": "error", "error": "RuntimeError: boom"}
    rows[2] = {**rows[2], "held": False, "error": "simulation diverged (MuJoCo bad_qacc x3)"}
    cut_short = json.dumps(rows[3])[:40]  # the last line of a killed run
    journal = "".join(json.dumps(r) + "\n" for r in rows) + cut_short
    (tmp_path / JOURNAL_NAME).write_text(journal)
    result = run_study(
        get_study("perturbation"),
        "tiny",
        tmp_path,
        executor="serial",
        progress=False,
        resume=True,
    )
    assert result.complete and result.summary["n_reused"] == 3
    assert _strip(result.rows[1:2]) == _strip(tiny_fresh.rows[1:2])  # recomputed
    assert result.rows[2] == rows[2]  # a diverged simulation is a result: kept as it is
    lines = _journal_lines(tmp_path)
    assert lines[4] == cut_short and json.loads(lines[5])["index"] == 1  # appended on a new line
    assert len(read_journal(tmp_path / JOURNAL_NAME)) == 5  # the cut line is skipped


def test_resume_matches_rows_by_content_and_ignores_other_designs(tmp_path, tiny_fresh, capsys):
    rows = [dict(r) for r in tiny_fresh.rows]
    other_seed = [{**r, "seed": r["seed"] + 1} for r in rows]  # same design, another seed
    moved = {**rows[3], "index": 17}  # e.g. computed under a narrower or wider design
    journal = other_seed + [moved]
    (tmp_path / JOURNAL_NAME).write_text("".join(json.dumps(r) + "\n" for r in journal))
    result = run_study(
        get_study("perturbation"),
        "tiny",
        tmp_path,
        executor="serial",
        progress=False,
        resume=True,
        limit=0,
    )
    assert result.summary["n_reused"] == 1 and not result.complete
    assert _strip(result.rows) == _strip([rows[3]])  # given the index of its job, 3
    assert "4 rows matching no job of this design ignored" in capsys.readouterr().err
    m = match_rows(get_study("perturbation").jobs("tiny", 0), journal)
    assert (sorted(m.rows), m.n_ignored, m.n_failed) == ([3], 4, 0)


def test_execute_reports_each_result_as_it_arrives():
    jobs = execution_order(get_study("k-sweep").jobs("quick", 0))[::-1][:3]
    seen: list[tuple[int, dict]] = []
    rows = execute(
        jobs,
        operator.attrgetter("labels"),
        executor="serial",
        on_result=lambda i, row: seen.append((i, row)),
    )
    assert [i for i, _ in seen] == [j.index for j in jobs]  # submitted in the order given
    assert rows == [j.labels for j in sorted(jobs, key=lambda j: j.index)]
    seen.clear()
    pooled = execute(
        jobs,
        operator.attrgetter("labels"),
        executor="process",
        workers=2,
        progress=False,
        on_result=lambda i, row: seen.append((i, row)),
    )
    assert pooled == rows and sorted(i for i, _ in seen) == sorted(j.index for j in jobs)


def test_cli_resume_and_limit_reach_run_study(tmp_path, monkeypatch, capsys):
    import wholehand.studies as studies
    from wholehand.cli.main import main

    calls: list[dict] = []

    def fake_run_study(study, **kwargs):
        calls.append({"study": study.name, **kwargs})
        summary = {"study": study.name, "complete": False, "n_planned": 4, "n_trials": 2}
        paths = [tmp_path / n for n in ("trials.csv", "summary.json", "p.png")]
        return runner.StudyResult([], summary, *paths, interrupted=len(calls) == 2)

    monkeypatch.setattr(studies, "run_study", fake_run_study)
    argv = ["study", "perturbation", "--size", "tiny", "--out", str(tmp_path), "--no-progress"]
    assert main([*argv, "--resume", "--limit", "2"]) == 0
    assert (calls[0]["resume"], calls[0]["limit"], calls[0]["size"]) == (True, 2, "tiny")
    assert main(argv) == 130  # interrupted: not a success for a shell script
    assert (calls[1]["resume"], calls[1]["limit"]) == (False, None)
    assert '"complete": false' in capsys.readouterr().out
    only = ["--only", "theta_deg=90", "--only", "method=qp", "--only", "theta_deg=60"]
    main([*argv, *only, "--grasps", "mine"])
    assert calls[2]["only"] == {"theta_deg": ("90", "60"), "method": ("qp",)}
    assert calls[2]["grasps"] == "mine"
    assert main([*argv, "--only", "theta_deg"]) == 2
    assert "write COLUMN=VALUE" in capsys.readouterr().err


def test_a_grasp_folder_expands_the_design_for_a_hand_without_stored_grasps(tmp_path):
    """``--grasps DIR`` on a user's hand that has no grasps of its own: the study's design runs
    over the folder's grasps (the same trials as over the shipped hand's stored ones, each
    reading its grasp from the folder)."""
    import shutil

    from wholehand.grasps.store import grasp_file
    from wholehand.models.hand_folders import shipped_hands_dir

    hand = tmp_path / "mine"
    hand.mkdir()
    shutil.copy(shipped_hands_dir() / "allegro_right" / "hand.toml", hand)
    found = tmp_path / "found"
    found.mkdir()
    shutil.copy(grasp_file("allegro_right", "077_rubiks_cube"), found)
    study = get_study("perturbation")
    with pytest.raises(ConfigError, match=r"no trial for hand '.*mine': it has no stored grasps"):
        runner.study_jobs(study, "tiny", 0, str(hand))  # no grasps of its own
    with pytest.raises(ConfigError, match=r"no grasps in .*mine of the study's objects"):
        runner.study_jobs(study, "tiny", 0, str(hand), grasps=hand)  # a folder without any
    jobs = runner.study_jobs(study, "tiny", 0, str(hand), grasps=found)
    shipped = runner.study_jobs(study, "tiny", 0, "allegro_right")

    def design(js):
        return [(j.labels, j.spec.object, j.spec.grasp, j.spec.theta_deg, j.spec.seed) for j in js]

    assert jobs and design(jobs) == design(shipped)
    assert {j.spec.grasp_file for j in jobs} == {str(found / "077_rubiks_cube.json")}


_ORPHAN_SCRIPT = """
import os, sys, time
from wholehand.studies.base import TrialJob
from wholehand.trials.trial import TrialSpec
from wholehand.studies.executors import execute

def slow(job):
    with open(os.path.join(sys.argv[1], f"worker-{os.getpid()}"), "w"):
        pass
    time.sleep(120)
    return {}

if __name__ == "__main__":
    jobs = [TrialJob(i, TrialSpec()) for i in range(2)]
    execute(jobs, slow, executor="process", workers=2, progress=False)
"""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(")")[-1].split()[0] != "Z"  # a zombie is dead
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads process states from /proc")
def test_pool_workers_die_with_a_killed_parent(tmp_path):
    script = tmp_path / "study.py"
    script.write_text(_ORPHAN_SCRIPT)
    parent = subprocess.Popen([sys.executable, str(script), str(tmp_path)])
    deadline = time.monotonic() + 60
    while len(list(tmp_path.glob("worker-*"))) < 2 and time.monotonic() < deadline:
        time.sleep(0.1)
    workers = [int(p.name.split("-")[1]) for p in tmp_path.glob("worker-*")]
    assert len(workers) == 2 and all(_alive(w) for w in workers)
    parent.kill()  # SIGKILL: no handler, no clean-up in the parent
    parent.wait()
    deadline = time.monotonic() + 10
    while any(_alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    orphans = [w for w in workers if _alive(w)]
    for w in orphans:  # leave nothing behind, even when the test fails
        os.kill(w, signal.SIGKILL)
    assert not orphans


def test_methods_replace_the_studys_own_in_place():
    from wholehand.studies.base import with_methods

    jobs = get_study("perturbation").jobs("tiny", 0)
    assert [j.labels["method"] for j in jobs] == ["qp", "feedforward"] * 2
    mine = with_methods(jobs, ("impedance", "qp_no_consistency", "qp"))
    assert [j.index for j in mine] == list(range(6))
    assert [j.spec.allocator for j in mine] == ["impedance", "qp_no_consistency", "qp"] * 2
    assert [j.labels["method"] for j in mine] == [j.spec.allocator for j in mine]
    assert [j.spec.theta_deg for j in mine] == [0.0] * 3 + [60.0] * 3
    with pytest.raises(PluginError, match="no plug-in named 'nope'.*installed: feedforward"):
        with_methods(jobs, ("qp", "nope"))
    with pytest.raises(ConfigError, match="compares no methods"):
        with_methods(get_study("k-sweep").jobs("tiny", 0), ("qp",))


def test_only_runs_the_matching_trials_of_the_design():
    from wholehand.studies.base import only_jobs
    from wholehand.studies.resume import continue_command

    study = get_study("perturbation")
    jobs = study.jobs("quick", 0)
    only = {"theta_deg": ("90", "60"), "method": ("qp",)}
    mine = only_jobs(jobs, only)
    expected = [j for j in jobs if j.spec.theta_deg in (60.0, 90.0) and j.labels["method"] == "qp"]
    assert 0 < len(mine) == len(expected) < len(jobs)
    assert [j.index for j in mine] == list(range(len(mine)))
    assert [j.spec for j in mine] == [j.spec for j in expected]  # seeds of the whole design
    assert only_jobs(jobs, {"object": ("077_rubiks_cube",), "grasp": ("1",)}) == [
        dataclasses.replace(j, index=i)
        for i, j in enumerate(
            j for j in jobs if j.spec.object == "077_rubiks_cube" and j.spec.grasp == 1
        )
    ]
    with pytest.raises(ConfigError, match="no column 'angle'; use one of .*theta_deg"):
        only_jobs(jobs, {"angle": ("90",)})
    with pytest.raises(ConfigError, match="no trial of the study has theta_deg in \\['45'\\]"):
        only_jobs(jobs, {"theta_deg": ("45",)})
    words = continue_command(study, Path("out/x"), "quick", 0, only=only)
    assert words.endswith("--only theta_deg=90 --only theta_deg=60 --only method=qp")


def _grasp_folder(folder, obj, n):
    """``folder/<obj>.json`` holding the first ``n`` stored Allegro power grasps of ``obj``."""
    from wholehand.grasps.store import grasp_file

    raw = json.loads(grasp_file("allegro_right", obj).read_text())
    raw["grasps"] = raw["grasps"][:n]
    folder.mkdir(exist_ok=True)
    (folder / f"{obj}.json").write_text(json.dumps(raw))
    return folder


def test_grasps_from_a_folder_replace_the_stored_ones(tmp_path):
    from wholehand.studies.base import with_grasps

    jobs = get_study("perturbation").jobs("quick", 0)  # cube and cups, grasps 0 and 1
    folder = _grasp_folder(tmp_path / "mine", "077_rubiks_cube", 1)
    mine = with_grasps(jobs, folder)
    cube = [j for j in jobs if j.spec.object == "077_rubiks_cube" and j.spec.grasp == 0]
    assert len(mine) == len(cube) > 0  # cups: no file there; cube grasp 1: past the file
    assert [j.index for j in mine] == list(range(len(mine)))
    assert {j.spec.grasp_file for j in mine} == {str(folder / "077_rubiks_cube.json")}
    assert [(j.labels, j.spec.seed) for j in mine] == [(j.labels, j.spec.seed) for j in cube]
    with pytest.raises(ConfigError, match="does not exist"):
        with_grasps(jobs, tmp_path / "absent")
    other = _grasp_folder(tmp_path / "other", "006_mustard_bottle", 1)
    with pytest.raises(ConfigError, match=r"\['006_mustard_bottle'\], none of the study's"):
        with_grasps(jobs, other)


def test_a_study_on_a_copy_of_the_stored_grasps_gives_the_same_rows(tmp_path, tiny_fresh):
    folder = _grasp_folder(tmp_path / "copy", "077_rubiks_cube", 1)
    result = run_study(
        get_study("perturbation"),
        "tiny",
        tmp_path / "out",
        executor="serial",
        progress=False,
        grasps=folder,
    )
    assert result.summary["grasps"] == str(folder)
    drop = lambda rows: [  # noqa: E731
        {k: v for k, v in r.items() if k != "grasp_file"} for r in _strip(rows)
    ]
    assert drop(result.rows) == drop(tiny_fresh.rows)
    assert {r["grasp_file"] for r in result.rows} == {str(folder / "077_rubiks_cube.json")}


def test_a_study_runs_a_users_hand_and_a_third_party_allocator(tmp_path, monkeypatch):
    """The tiny perturbation study on a hand folder of the user's (the Allegro's hand.toml with
    one grasp file), comparing the built-in QP with a third party's allocator."""
    import shutil

    from test_registry import _make_distribution

    from wholehand import registry
    from wholehand.grasps.store import grasp_file
    from wholehand.models.hand_folders import shipped_hands_dir

    site = _make_distribution(
        tmp_path,
        "acme-allocator",
        "acme_allocator",
        "wholehand.allocators",
        "acme_qp",
        "from wholehand_plugins.qp import QPAllocator\n\nclass Plugin(QPAllocator):\n    pass\n",
    )
    monkeypatch.syspath_prepend(str(site))
    registry.refresh()
    hand = tmp_path / "mine"
    (hand / "grasps").mkdir(parents=True)
    shutil.copy(shipped_hands_dir() / "allegro_right" / "hand.toml", hand)
    shutil.copy(grasp_file("allegro_right", "077_rubiks_cube"), hand / "grasps")
    result = run_study(
        get_study("perturbation"),
        size="tiny",
        out=tmp_path / "out",
        executor="serial",
        progress=False,
        hand=str(hand),
        methods=("qp", "acme_qp"),
    )
    rows = _read(result.csv_path)
    assert [(r["method"], r["hand"]) for r in rows] == [
        ("qp", str(hand)),
        ("acme_qp", str(hand)),
    ] * 2
    assert all(r["held"] == "True" for r in rows)
    empty = tmp_path / "empty"
    empty.mkdir()
    shutil.copy(shipped_hands_dir() / "allegro_right" / "hand.toml", empty)
    with pytest.raises(ConfigError, match="no trial for hand.*generate them"):
        run_study(get_study("perturbation"), size="tiny", out=tmp_path / "o2", hand=str(empty))


def test_gravity_study_pairs_its_trials_with_the_perturbation_study():
    """Gravity on in every trial, the weight balanced by qp+weight and qp+weight+fingers, the
    fingers' weight by the latter alone, and the perturbation study's seeds for the same
    (object, grasp, angle, repeat): the same pull axes."""
    gravity = get_study("gravity").jobs("full", seed=0)
    assert len(gravity) == 50 * 3 * (1 + 3 * 5)
    assert {j.labels["method"] for j in gravity} == {"qp", "qp+weight", "qp+weight+fingers"}
    assert all(j.spec.gravity and j.spec.allocator == "qp" for j in gravity)
    assert all(j.spec.balance_weight == (j.labels["method"] != "qp") for j in gravity)
    assert all(
        j.spec.gravity_compensation == (j.labels["method"] == "qp+weight+fingers") for j in gravity
    )
    seeds = {
        (j.spec.object, j.spec.grasp, j.spec.theta_deg, j.labels["repeat"]): j.spec.seed
        for j in get_study("perturbation").jobs("full", seed=0)
    }
    for j in gravity:
        assert (
            j.spec.seed
            == seeds[(j.spec.object, j.spec.grasp, j.spec.theta_deg, j.labels["repeat"])]
        )


def test_balancing_the_weight_needs_gravity(allegro):
    from wholehand.trials.trial import TrialSpec, set_up_trial

    with pytest.raises(ConfigError, match="balance_weight=True needs gravity=True"):
        set_up_trial(TrialSpec(balance_weight=True), allegro)
    with pytest.raises(ConfigError, match="gravity_compensation=True needs gravity=True"):
        set_up_trial(TrialSpec(gravity_compensation=True), allegro)
    trial = set_up_trial(TrialSpec(balance_weight=True, gravity=True), allegro)
    mass = trial.obj.mass
    np.testing.assert_allclose(
        trial.regulation._extra["external_wrench"], [0.0, 0.0, -9.81 * mass, 0.0, 0.0, 0.0]
    )
    assert "external_wrench" not in set_up_trial(TrialSpec(gravity=True), allegro).regulation._extra


def test_rate_study_pairs_rates_and_methods_on_the_perturbation_seeds():
    rate = get_study("rate").jobs("full", seed=0)
    # 5 objects x 10 grasps x 2 angles x 3 axes, 7 rates x 2 methods.
    assert len(rate) == 50 * 2 * 3 * 7 * 2
    assert {j.spec.control_rate for j in rate} == {30.0, 66.0, 100.0, 200.0, 227.0, 500.0, 1000.0}
    assert all(j.labels["rate_hz"] == j.spec.control_rate for j in rate)
    assert all(j.spec.allocator == j.labels["method"] for j in rate)
    seeds = {
        (j.spec.object, j.spec.grasp, j.spec.theta_deg, j.labels["repeat"]): j.spec.seed
        for j in get_study("perturbation").jobs("full", seed=0)
    }
    assert all(
        j.spec.seed == seeds[(j.spec.object, j.spec.grasp, j.spec.theta_deg, j.labels["repeat"])]
        for j in rate
    )


def _rate_rows(held_by_rate):
    """Rows of one method and angle: grasp g at rate r held in the trials ``held_by_rate[r][g]``."""
    rows = []
    for rate, grasps in held_by_rate.items():
        for g, trials in enumerate(grasps):
            for held in trials:
                row = {"object": "o", "grasp": g, "hand": "h", "held": held, "error": ""}
                rows.append({**row, "method": "qp", "theta_deg": 90.0, "rate_hz": rate})
    return rows


def test_rate_summary_compares_every_rate_with_the_fastest_by_paired_grasps():
    from wholehand.studies.rate import enough_rate, paired_difference

    rows = _rate_rows(
        {
            30.0: [[False, False], [False, True], [True, True]],  # 0, 0.5, 1
            100.0: [[True, False], [True, True], [True, True]],  # 0.5, 1, 1
            1000.0: [[True, True], [True, True], [True, False]],  # 1, 1, 0.5
        }
    )
    slow = [r for r in rows if r["rate_hz"] == 30.0]
    fast = [r for r in rows if r["rate_hz"] == 1000.0]
    diff, se, n = paired_difference(slow, fast)
    d = np.array([-1.0, -0.5, 0.5])
    assert (diff, n) == (pytest.approx(d.mean()), 3)
    assert se == pytest.approx(d.std(ddof=1) / np.sqrt(3))
    summary = get_study("rate").summarise(rows)
    by_rate = {g["rate_hz"]: g for g in summary["groups"]}
    assert by_rate[1000.0]["diff_to_fastest"] == 0.0
    # 100 Hz: differences (-0.5, 0, 0.5): mean 0; 30 Hz: mean -1/3, SE 0.44: within 2 SE.
    assert by_rate[100.0]["diff_to_fastest"] == pytest.approx(0.0)
    assert summary["enough_rate"] == [{"method": "qp", "theta_deg": 90.0, "enough_hz": 30.0}]
    groups = [
        {"rate_hz": 30.0, "diff_to_fastest": -0.4, "diff_se": 0.1, "n_paired": 5},
        {"rate_hz": 100.0, "diff_to_fastest": -0.15, "diff_se": 0.1, "n_paired": 5},
        {"rate_hz": 1000.0, "diff_to_fastest": 0.0, "diff_se": 0.0, "n_paired": 5},
    ]
    assert enough_rate(groups) == 100.0  # 30 Hz: 4 SE short; 100 Hz: 1.5 SE, not short
    groups[1]["diff_to_fastest"] = -0.25
    assert enough_rate(groups) == 1000.0  # 100 Hz: 2.5 SE short
    groups[1]["diff_to_fastest"] = +0.4
    assert enough_rate(groups) == 100.0  # holding more is no shortfall


def test_tiny_rate_study_runs_its_rates(tmp_path):
    result = run_study(get_study("rate"), "tiny", tmp_path, executor="serial", progress=False)
    by_rate = {r["rate_hz"]: r for r in result.rows}
    assert set(by_rate) == {30.0, 1000.0}
    assert by_rate[1000.0]["cycles"] == pytest.approx(by_rate[30.0]["cycles"] * 1000 / 30, rel=0.05)
    assert result.plot_path.is_file() and result.summary["enough_rate"][0]["method"] == "qp"


def test_a_second_run_on_a_folder_in_use_is_refused_with_the_holder_named(tmp_path, capsys):
    """One writer per folder: while another process holds it, a run is refused (its journal
    untouched); once that process is killed, a run goes ahead."""
    import signal
    import subprocess
    import sys

    from wholehand.cli.main import main

    folder = tmp_path / "run"
    folder.mkdir()
    (folder / JOURNAL_NAME).write_text('{"index": 0}\n')
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, pathlib\n"
            "from wholehand.studies.folder_lock import study_folder_lock\n"
            "with study_folder_lock(pathlib.Path(sys.argv[1])):\n"
            "    print('held', flush=True); sys.stdin.read()\n",
            str(folder),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        args = ["study", "perturbation", "--size", "tiny", "--out", str(folder), "--limit", "0"]
        assert main([*args, "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert f"is in use by another study run (pid {holder.pid} on " in err
        assert (folder / JOURNAL_NAME).read_text() == '{"index": 0}\n'
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert main([*args, "--no-progress"]) == 0  # the killed holder left no stale lock
    assert (folder / JOURNAL_NAME).read_text() == ""  # a fresh run, 0 trials this time


def _posed_record(rows: list[tuple[int, np.ndarray, np.ndarray]]) -> RunRecord:
    """A record of (phase, hand base pose, object pose) rows, every cycle held."""
    import pinocchio as pin

    record = RunRecord(phases=["settle", "load"])
    extra = {k: np.zeros(2) for k in RunRecord.FIELDS}
    extra.update({k: np.zeros((0, 3)) for k in getattr(RunRecord, "CONTACT_FIELDS", ())})
    extra["contact_link"] = np.zeros(0, dtype=int)
    for i, (phase, wMb, wMo) in enumerate(rows):
        record.append(
            **{
                **extra,
                "t": 0.005 * i,
                "phase": phase,
                "status": "ok",
                "held": True,
                "p_object": wMo[:3, 3],
                "r_object": pin.log3(wMo[:3, :3]),
                "p_base": wMb[:3, 3],
                "r_base": pin.log3(wMb[:3, :3]),
            }
        )
    return record


def test_the_strict_criterion_measures_the_slip_in_the_hand_from_the_settled_grasp():
    """The object's pose in the hand base's frame, from the end of the settle phase to the last
    cycle: carried rigidly by a moving hand it has not slipped; slid 30 mm and turned 25 deg in
    a still hand it has, and the paper's criterion still says held."""
    import pinocchio as pin

    from wholehand.trials.outcome import STRICT_SLIP_MM, outcome_of

    def pose(xyz, yaw_deg=0.0):
        M = np.eye(4)
        M[:3, :3] = pin.rpy.rpyToMatrix(0.0, 0.0, np.radians(yaw_deg))
        M[:3, 3] = xyz
        return M

    bMo = pose([0.0, 0.0, 0.1])
    moved_hand = pose([0.05, 0.02, 0.0], 90.0)
    carried = _posed_record(
        [(0, pose([0, 0, 0]), pose([0.0, 0.0, 0.09])), (0, pose([0, 0, 0]), bMo),
         (1, moved_hand, moved_hand @ bMo)]
    )  # fmt: skip
    out = outcome_of(carried)
    assert out.held and out.held_strict
    assert out.slip_mm == pytest.approx(0.0, abs=1e-9) and out.slip_deg == pytest.approx(0.0)
    slid = _posed_record(
        [(0, pose([0, 0, 0]), bMo), (1, pose([0, 0, 0]), pose([0.03, 0.0, 0.1], 25.0))]
    )
    out = outcome_of(slid)
    assert out.held and not out.held_strict
    assert out.slip_mm == pytest.approx(30.0) and out.slip_deg == pytest.approx(25.0)
    assert out.slip_mm > STRICT_SLIP_MM
    row = record_row(slid)
    assert row["held"] is True and row["held_strict"] is False and row["slip_mm"] == 30.0


def test_success_stats_give_the_strict_rate_only_where_every_row_carries_it():
    rows = [
        {"hand": "h", "object": "o", "grasp": g, "held": True, "held_strict": g == 0}
        for g in range(4)
    ]
    stats = success_stats(rows)
    assert stats["success"] == 1.0 and stats["success_strict"] == pytest.approx(0.25)
    del rows[1]["held_strict"]  # a row of a study run before the criterion
    assert np.isnan(success_stats(rows)["success_strict"])


def test_a_study_records_the_code_it_started_with(tmp_path, monkeypatch):
    """A commit made while a study runs is not the code its trials ran: the summary keeps the
    provenance taken before the first trial."""
    calls = iter(["first", "second", "third"])
    monkeypatch.setattr(runner, "provenance", lambda: {"commit": next(calls)})
    result = run_study(
        get_study("perturbation"), "tiny", tmp_path, executor="serial", progress=False
    )
    assert json.loads(result.summary_path.read_text())["provenance"] == {"commit": "first"}
