"""`wholehand study grasp-synthesis`: its design, its summary and one tiny run."""

from __future__ import annotations

import json
import math
from collections import Counter

import pytest

from wholehand.grasps.generate import generate_grasps
from wholehand.grasps.optimized import synthesize_grasps
from wholehand.models.object_catalogue import available_objects
from wholehand.studies import get_study, run_study
from wholehand.studies.grasp_synthesis import COUNT, GENERATORS, SETTINGS, STYLES
from wholehand.studies.models import model


def test_the_full_design_covers_every_ycb_object_in_both_settings_with_both_generators():
    jobs = get_study("grasp-synthesis").jobs("full", seed=0)
    objects = available_objects()
    assert len(objects) == 78
    assert len(jobs) == len(objects) * len(SETTINGS) * len(GENERATORS)
    assert {j.kind for j in jobs} == {"grasp_generation"}
    assert {(j.labels["generator"], j.labels["budget"]) for j in jobs} == {
        ("preshape", 400),
        ("optimize", 128),
    }
    # on a table the optimiser tries pinch after power; the pre-shape makes power grasps alone
    assert {(j.labels["setting"], j.labels["generator"], j.labels["styles"]) for j in jobs} == {
        ("air", "preshape", "power"),
        ("air", "optimize", "power"),
        ("table", "preshape", "power"),
        ("table", "optimize", "power,pinch"),
    }
    seeds: dict[tuple[str, str], set[int]] = {}
    for job in jobs:
        seeds.setdefault((job.spec.object, job.labels["setting"]), set()).add(job.spec.seed)
    # both generators of an (object, setting) share one seed; every (object, setting) its own
    assert all(len(s) == 1 for s in seeds.values())
    assert len({next(iter(s)) for s in seeds.values()}) == len(seeds)


def _row(obj, generator, grasps, seconds, rejections, error="", by_style=None):
    return {
        "object": obj,
        "setting": "air",
        "generator": generator,
        "grasps": grasps,
        "candidates": 10,
        "wall_time_s": seconds,
        "rejections": json.dumps(rejections),
        "by_style": json.dumps(
            by_style or {"power": {"grasps": grasps, "candidates": 10, "seconds": seconds}}
        ),
        "error": error,
    }


def test_the_summary_counts_objects_grasps_and_seconds_per_grasp():
    rows = [
        _row(
            "a",
            "optimize",
            4,
            8.0,
            {"off": 2},
            by_style={
                "power": {"grasps": 0, "candidates": 10, "seconds": 5.0},
                "pinch": {"grasps": 4, "candidates": 10, "seconds": 3.0},
            },
        ),
        _row("b", "optimize", 0, 6.0, {"off": 3, "moved": 1}),
        _row("c", "optimize", 2, 4.0, {"moved": 1}),
        _row("d", "optimize", 0, 1.0, {}, error="RuntimeError: broken mesh"),
        _row("a", "preshape", 0, 2.0, {"table": 10}),
    ]
    groups = get_study("grasp-synthesis").summarise(rows)["groups"]
    optimize, preshape = groups
    assert optimize["generator"] == "optimize" and preshape["generator"] == "preshape"
    assert optimize["n_objects"] == 3 and optimize["n_errors"] == 1
    assert optimize["objects_with_grasp"] == 2
    assert optimize["share_with_grasp"] == pytest.approx(2 / 3)
    assert optimize["grasps"] == 6 and optimize["grasps_per_object"] == pytest.approx(2.0)
    assert optimize["seconds_per_grasp"] == pytest.approx(18.0 / 6)  # errored row left out
    assert optimize["rejections"] == {"off": 5, "moved": 2}
    assert optimize["objects_without_grasp"] == ["b"]
    assert optimize["by_style"] == {
        "pinch": {"objects_with_grasp": 1, "grasps": 4, "seconds": 3.0},
        "power": {"objects_with_grasp": 1, "grasps": 2, "seconds": 15.0},
    }
    assert preshape["grasps"] == 0 and math.isnan(preshape["seconds_per_grasp"])


def test_a_tiny_run_finds_what_the_generators_find_by_themselves(tmp_path):
    study = get_study("grasp-synthesis")
    result = run_study(study, "tiny", tmp_path, executor="serial", progress=False)
    assert len(result.rows) == 4 and not any(r["error"] for r in result.rows)
    hand = model("hand", "allegro_right")
    for row in result.rows:
        assert 0 <= row["grasps"] <= min(COUNT, row["candidates"])
        by_style = json.loads(row["by_style"])
        styles = STYLES[row["setting"]] if row["generator"] == "optimize" else ("power",)
        assert list(by_style) == list(styles[: len(by_style)]) and "power" in by_style
        make = synthesize_grasps if row["generator"] == "optimize" else generate_grasps
        found, rejected = 0, Counter[str]()
        for style, got in by_style.items():  # each style for what the ones before left
            assert found < COUNT and got["candidates"] <= row["budget"]
            grasps, info = make(
                hand,
                model("object", row["object"]),
                count=COUNT - found,
                seed=row["seed"],
                max_candidates=row["budget"],
                style=style,
                on_table=row["setting"] == "table",
            )
            assert (len(grasps), info["candidates_tried"]) == (got["grasps"], got["candidates"])
            found += len(grasps)
            rejected.update(info["rejected"])
        assert row["grasps"] == found
        assert found == COUNT or len(by_style) == len(styles)  # a style left out only when done
        assert json.loads(row["rejections"]) == dict(rejected)
    assert (tmp_path / "grasp-synthesis.png").stat().st_size > 0
    # --resume finds every row finished: nothing runs again.
    again = run_study(study, "tiny", tmp_path, executor="serial", progress=False, resume=True)
    assert again.summary["n_reused"] == 4 and again.rows == result.rows
