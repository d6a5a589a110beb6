"""The reach check of ``grasps generate --require-reach`` and ``grasps check``: a grasp is kept
only if the reacher closes it in the episode of ``wholehand reach``."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil

import numpy as np
import pytest

from wholehand.errors import ConfigError
from wholehand.grasps.checks import all_of
from wholehand.grasps.store import Grasp, load_grasps
from wholehand.reaching.reach_check import reach_check


@pytest.fixture(scope="module")
def cups():
    from wholehand.models.object_catalogue import load_object

    return load_object("065-f_cups")


@pytest.fixture(scope="module")
def table_grasp() -> Grasp:
    return load_grasps("allegro_right", "065-f_cups", "power", on_table=True)[0]


def shifted(grasp: Grasp, offset: tuple[float, float, float]) -> Grasp:
    """The grasp with its base moved by ``offset`` [m] in the object frame."""
    oMb = grasp.oMb.copy()
    oMb[:3, 3] += offset
    return dataclasses.replace(grasp, oMb=oMb)


def test_a_table_grasp_the_reacher_closes_passes(allegro, cups, table_grasp):
    check = reach_check(allegro, cups, "power", 2.5, on_table=True, seeds=(0,))
    assert check(table_grasp) is None


def test_a_grasp_above_the_object_never_closes(allegro, cups, table_grasp):
    # 10 cm up the table's normal the fingers close on air above the cups: nothing is touched.
    up = 0.10 * np.asarray(table_grasp.extra["table_up"])
    check = reach_check(allegro, cups, "power", 2.0, on_table=True, seeds=(0,))
    assert check(shifted(table_grasp, tuple(up))) == "the reacher did not close it within 2 s"


def test_a_grasp_below_the_table_top_is_named(allegro, cups, table_grasp):
    # 5 cm down the table's normal the hand (1.2 cm above the table when made) is in the table.
    down = -0.05 * np.asarray(table_grasp.extra["table_up"])
    check = reach_check(allegro, cups, "power", 2.0, on_table=True, seeds=(0,))
    reason = check(shifted(table_grasp, tuple(down)))
    assert reason == "the grasp or its pre-grasp comes too near the table"


def test_a_grasp_in_the_air_the_reacher_closes_passes(allegro):
    from wholehand.models.object_catalogue import load_object

    cube = load_object("077_rubiks_cube")
    grasp = load_grasps("allegro_right", "077_rubiks_cube", "power")[5]
    check = reach_check(allegro, cube, "power", 2.5, on_table=False, seeds=(0,))
    assert check(grasp) is None  # closed while held out, kept once the person lets go


@pytest.mark.parametrize("within", [0.0, -1.0, float("nan"), float("inf")])
def test_a_bad_time_limit_is_refused(allegro, cups, within):
    with pytest.raises(ConfigError, match="--require-reach must be > 0"):
        reach_check(allegro, cups, "power", within, on_table=True)


def test_an_unknown_grasp_style_is_named(allegro, cups):
    with pytest.raises(ConfigError, match="has no grasp style 'wrap'; its styles: "):
        reach_check(allegro, cups, "wrap", 2.0, on_table=True)


def test_all_of_fails_with_the_first_reason():
    def fails(reason):
        return lambda grasp: reason

    grasp = Grasp(0, np.eye(4), {})
    assert all_of([]) is None
    one = fails(None)
    assert all_of([one]) is one
    both = all_of([fails(None), fails("second"), fails("third")])
    assert both is not None and both(grasp) == "second"
    ok = all_of([fails(None), fails(None)])
    assert ok is not None and ok(grasp) is None


def test_grasps_check_keeps_the_passing_grasps_with_their_ids(tmp_path, monkeypatch, capsys):
    import wholehand.grasps.store as store
    import wholehand.reaching.reach_check as reach
    from wholehand.cli.main import main

    shipped = store.grasp_file("allegro_right", "065-f_cups", "power", on_table=True)
    copy = tmp_path / shipped.name
    shutil.copy(shipped, copy)
    n = len(load_grasps(copy))
    monkeypatch.setattr(store, "grasp_file", lambda *args: copy)
    seen: list[tuple[str, float, bool]] = []

    def odd_ids_fail(hand, obj, style, within, on_table):
        seen.append((style, within, on_table))
        return lambda grasp: "odd" if grasp.id % 2 else None

    monkeypatch.setattr(reach, "reach_check", odd_ids_fail)
    args = ["grasps", "check", "--object", "065-f_cups", "--on-table", "--require-reach", "2.5"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert seen == [("power", 2.5, True)]
    assert "grasp 1: odd" in out and f"{(n + 1) // 2} of {n} grasps pass" in out
    assert len(load_grasps(copy)) == n  # without --keep-passing the file stays

    assert main([*args, "--keep-passing"]) == 0
    kept = load_grasps(copy)
    assert [g.id for g in kept] == list(range(0, n, 2))
    generator = json.loads(copy.read_text())["generator"]
    assert generator["checked"].startswith("--require-reach 2.5: kept grasps [0, 2")


def test_grasps_check_needs_a_check(capsys):
    from wholehand.cli.main import main

    assert main(["grasps", "check", "--object", "065-f_cups"]) != 0
    assert "give --require-reach SECONDS, --require-hold DEG or both" in capsys.readouterr().err


def test_a_settled_angle_past_the_slack_is_named_and_refused_by_loading(allegro):
    from wholehand.grasps.store import LIMIT_SLACK, joint_past_limits

    q = allegro.q_lower.copy()
    assert joint_past_limits(allegro, q) is None
    q[3] = allegro.q_lower[3] - 0.5 * LIMIT_SLACK  # inside the slack: storable
    assert joint_past_limits(allegro, q) is None
    q[3] = allegro.q_lower[3] - 2.0 * LIMIT_SLACK
    name = allegro.joint_names[3]
    problem = joint_past_limits(allegro, q)
    assert problem is not None and problem.startswith(f"joint {name!r} at {q[3]:.4g} rad")
    grasp = Grasp(-1, np.eye(4), dict(zip(allegro.joint_names, q.tolist(), strict=True)))
    with pytest.raises(ConfigError, match=re.escape(f"grasp -1: {problem}")):
        grasp.q_array(allegro)
