"""The tracking study: its design around the paper's point, and a tiny run."""

from __future__ import annotations

import dataclasses

import pytest

from wholehand.studies import get_study, run_study
from wholehand.studies.base import protocol_for
from wholehand.studies.tracking import CONDITIONS, FACTORS, PAPER_POINT, pull_start
from wholehand.trials.protocol import PerturbationProtocol


def test_each_condition_moves_one_factor_from_the_papers_point():
    fields = {
        "rate": "rate_hz",
        "latency": "latency_s",
        "noise": "noise_mm",
        "dropout": "dropout_s",
    }
    for cond in CONDITIONS:
        differs = {
            f
            for f in ("rate_hz", "latency_s", "noise_mm", "noise_deg", "dropout_s")
            if getattr(cond, f) != getattr(PAPER_POINT, f)
        }
        if cond.factor in FACTORS:
            expected = {fields[cond.factor]} | ({"noise_deg"} if cond.factor == "noise" else set())
            assert differs == expected, cond
        elif cond.factor == "corner":
            assert differs == set(fields.values()) | {"noise_deg"}
    levels = {
        f: sorted({c.level() for c in CONDITIONS if c.factor == f} | {_paper_level(f)})
        for f in FACTORS
    }
    assert levels == {
        "rate": [15.0, 30.0, 60.0, 200.0],
        "latency": [0.0, 33.0, 66.0, 100.0],
        "noise": [0.0, 1.0, 3.0],
        "dropout": [0.0, 0.2, 1.0],
    }


def _paper_level(factor):
    return dataclasses.replace(PAPER_POINT, factor=factor).level()


def test_the_full_design_pairs_methods_and_conditions_on_each_grasp():
    jobs = get_study("tracking").jobs("full", seed=0)
    assert len(jobs) == 50 * len(CONDITIONS) * 4
    by_grasp = {}
    for job in jobs:
        s = job.spec
        by_grasp.setdefault((s.object, s.grasp), set()).add(s.seed)
        tracking = s.tracking
        if "noise_seed" in tracking:
            assert tracking["noise_seed"] == s.seed  # the same draws for every method
        if job.labels["method"] == "qp@current":
            assert s.allocator == "qp" and s.estimate_at == "current"
        else:
            assert s.estimate_at == "object_stamp"
    assert all(len(seeds) == 1 for seeds in by_grasp.values())  # one pull axis per grasp
    # Grasp rank outermost: the first tenth of a run has every object's first grasp.
    first = jobs[: 5 * len(CONDITIONS) * 4]
    assert {(j.spec.object, j.spec.grasp) for j in first} == {(o, 0) for o, _ in by_grasp}


def test_the_dropout_starts_when_the_pull_starts():
    full = PerturbationProtocol(theta_deg=60.0)
    assert pull_start({}, 60.0) == pytest.approx(full.settle_time + 6 * full.load_duration)
    job = next(
        j for j in get_study("tracking").jobs("quick", seed=0) if j.labels["condition"] == "corner"
    )
    start, duration = job.spec.tracking["dropouts"][0]
    assert start == pytest.approx(pull_start(protocol_for("quick"), 60.0)) and duration == 1.0
    with pytest.raises(ValueError, match="no pull"):
        pull_start({}, 0.0)


def test_a_tiny_run_where_the_exact_pose_makes_the_estimate_time_irrelevant(tmp_path):
    """With the exact pose every cycle, q(stamp_object) is the current q: ``qp`` and
    ``qp@current`` give the same row. Under the corner's tracker they differ."""
    result = run_study(get_study("tracking"), "tiny", tmp_path, executor="serial", progress=False)
    rows = {(r["method"], r["condition"]): r for r in result.rows}
    assert len(rows) == 4 and all(not r["error"] for r in rows.values())
    keys = ("held", "cycles", "final_displacement_mm", "contacts_mean", "ok_fraction")
    exact = [tuple(rows[(m, "exact")][k] for k in keys) for m in ("qp", "qp@current")]
    assert exact[0] == exact[1]
    corner = [rows[(m, "corner")]["final_displacement_mm"] for m in ("qp", "qp@current")]
    assert corner[0] != corner[1] and rows[("qp", "corner")]["final_displacement_mm"] != exact[0][2]
    summary = result.summary
    assert {(g["method"], g["condition"]) for g in summary["groups"]} == set(rows)
    assert (tmp_path / "tracking.png").stat().st_size > 0
