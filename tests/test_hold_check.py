"""Grasps kept only if they pass a further check: the hook of both generators, and the
perturbation-protocol check of ``grasps generate --require-hold``."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from wholehand.grasps.generate import GraspGenerator
from wholehand.grasps.store import load_grasps
from wholehand.models.objects import ObjectModel
from wholehand.trials.hold_check import protocol_check


@pytest.fixture(scope="module")
def cube(allegro):
    from wholehand.models.object_catalogue import load_object

    return load_object("077_rubiks_cube")


def test_a_failed_check_rejects_the_grasp_with_its_reason_and_the_search_goes_on(allegro):
    box = ObjectModel.box((0.07, 0.14, 0.168), mass=0.1, name="table_box")
    plain = GraspGenerator(allegro, box, on_table=True).generate(2, 0, 200)
    assert len(plain) == 2
    checked: list[int] = []

    def reject_the_first(grasp):
        checked.append(grasp.extra["candidate"])
        return "the test rejects it" if len(checked) == 1 else None

    generator = GraspGenerator(allegro, box, on_table=True)
    kept = generator.generate(2, 0, 200, check=reject_the_first)
    assert generator.rejections["the test rejects it"] == 1
    # The first grasp found is rejected, the search goes on and keeps the next two it finds.
    assert checked[0] == plain[0].extra["candidate"]
    assert [g.extra["candidate"] for g in kept] == checked[1:]
    assert len(kept) == 2 and [g.id for g in kept] == [0, 1]


def test_the_protocol_check_keeps_a_held_grasp_and_names_the_phase_of_a_lost_one(allegro, cube):
    check = protocol_check(allegro, cube, 60.0)
    grasp = load_grasps("allegro_right", "077_rubiks_cube", "power")[0]
    assert check(grasp) is None  # held through every phase, as `wholehand run` shows
    # The same grasp with the fingers opened by 0.6 rad barely touches: without gravity the
    # object floats through the settling, and the first load pushes it out.
    opened = dict(grasp.q)
    for name in allegro.joint_names:
        j = allegro.model.joints[allegro.model.getJointId(name)].idx_q
        opened[name] = float(np.clip(grasp.q[name] - 0.6, allegro.q_lower[j], allegro.q_upper[j]))
    reason = check(dataclasses.replace(grasp, q=opened))
    assert reason is not None and reason == "lost in the 60 deg protocol (phase load +x)"


def test_require_hold_is_refused_on_a_table(capsys):
    from wholehand.cli.main import main

    code = main(["grasps", "generate", "--on-table", "--require-hold", "60", "--out", "/tmp/x"])
    assert code != 0
    assert "--require-hold runs the perturbation protocol in the air" in capsys.readouterr().err


@pytest.mark.parametrize("rate", ["0", "1.5", "nan"])
def test_a_hold_rate_outside_zero_to_one_is_refused(capsys, rate):
    from wholehand.cli.main import main

    argv = ["grasps", "generate", "--require-hold", "60", "--hold-trials", "5", "--hold-rate"]
    assert main([*argv, rate, "--object", "077_rubiks_cube", "--out", "/tmp/x"]) == 2
    assert f"--hold-rate {rate}: give a share in (0, 1]" in capsys.readouterr().err


def test_ctrl_c_ends_the_search_with_the_grasps_found_so_far(allegro, monkeypatch):
    box = ObjectModel.box((0.07, 0.14, 0.168), mass=0.1, name="table_box")
    calls: list[int] = []

    def interrupt_at_the_second(grasp):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return None

    generator = GraspGenerator(allegro, box, on_table=True)
    kept = generator.generate(3, 0, 200, check=interrupt_at_the_second)
    assert len(kept) == 1 and generator.interrupted

    # The optimiser too: interrupted while it optimises its first batch.
    from wholehand.grasps import optimized
    from wholehand.models.object_catalogue import load_object

    def interrupted(self, n, seed):
        raise KeyboardInterrupt

    monkeypatch.setattr(optimized.GraspSynthesizer, "optimise", interrupted)
    grasps, info = optimized.synthesize_grasps(allegro, load_object("077_rubiks_cube"), 2)
    assert grasps == [] and info["interrupted"] is True and info["candidates_tried"] == 0


def test_the_cli_writes_an_interrupted_search_and_stops(tmp_path, monkeypatch, capsys):
    import wholehand.grasps.generate as generate
    from wholehand.cli.main import main
    from wholehand.grasps.store import Grasp

    tried: list[str] = []

    def fake(hand, obj, count, seed, max_candidates, progress, style, on_table, check):
        tried.append(obj.name)
        found = [Grasp(0, np.eye(4), dict.fromkeys(hand.joint_names, 0.0))]
        return found, {"candidates_tried": 7, "rejected": {}, "interrupted": True}

    monkeypatch.setattr(generate, "generate_grasps", fake)
    args = ["grasps", "generate", "--object", "077_rubiks_cube", "--object", "065-f_cups"]
    assert main([*args, "--out", str(tmp_path)]) == 130
    assert tried == ["077_rubiks_cube"]  # the next object is not tried
    assert (tmp_path / "077_rubiks_cube.json").is_file()
    assert "1 grasps from 7 candidates (interrupted" in capsys.readouterr().out


def test_several_trials_pull_about_successive_seeds_and_need_their_share(
    allegro, cube, monkeypatch
):
    """--hold-trials N: the protocol with seeds 0..N-1 (here held with seeds 0, 2 and 3 only),
    the grasp kept once its share of holds is reached, the search for it stopped once the
    share is out of reach."""
    import wholehand.trials.hold_check as hold_check

    seeds: list[int] = []

    def fake_run(spec, hand, obj, grasp):
        seeds.append(spec.seed)
        return spec.seed

    def fake_outcome(seed):
        lost = seed not in (0, 2, 3)
        return _Outcome(held=not lost, failure_phase="rotate" if lost else None)

    monkeypatch.setattr(hold_check, "run_trial", fake_run)
    monkeypatch.setattr(hold_check, "outcome_of", fake_outcome)
    grasp = load_grasps("allegro_right", "077_rubiks_cube", "power")[0]
    assert protocol_check(allegro, cube, 60.0, trials=5, min_rate=0.6)(grasp) is None
    assert seeds == [0, 1, 2, 3]  # 3 of 5 held by the fourth
    seeds.clear()
    reason = protocol_check(allegro, cube, 60.0, trials=5, min_rate=0.8)(grasp)
    assert reason == "held in fewer than 4 of 5 60 deg protocols (most often lost in phase rotate)"
    assert seeds == [0, 1, 2, 3, 4]
    seeds.clear()
    assert protocol_check(allegro, cube, 60.0, trials=5, min_rate=1.0)(grasp) is not None
    assert seeds == [0, 1]  # 5 of 5 out of reach after the first loss
    with pytest.raises(ValueError, match="0 < min_rate <= 1"):
        protocol_check(allegro, cube, 60.0, trials=3, min_rate=0.0)


@dataclasses.dataclass
class _Outcome:
    held: bool = True
    failure_phase: str | None = None
    error: str | None = None
