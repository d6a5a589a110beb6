"""DexGraspBench's load test: its pose measure, its object, a push timed against free-body
kinematics, and the study."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from wholehand_plugins.mujoco.backend import MujocoBackend

from wholehand.backends.command import Command
from wholehand.errors import ConfigError
from wholehand.loop.control_loop import ControlLoop
from wholehand.loop.stage import Stage, StageOutput
from wholehand.models.object_catalogue import load_object
from wholehand.models.objects import ObjectModel
from wholehand.trials.dexgraspbench import (
    ACCELERATION,
    MASS,
    MAX_ROTATION_DEG,
    MAX_TRANSLATION,
    Push,
    bench_object,
    pose_change,
    run_load_test,
)
from wholehand.trials.trial import TrialSpec


def test_pose_change_is_the_translation_and_the_rotation_angle() -> None:
    start = np.eye(4)
    start[:3, :3] = pin.exp3(np.array([0.2, -0.1, 0.4]))
    start[:3, 3] = [0.1, 0.2, 0.3]
    moved = start.copy()
    moved[:3, :3] = start[:3, :3] @ pin.exp3(np.deg2rad(20.0) * np.array([0.0, 0.6, 0.8]))
    moved[:3, 3] += [0.03, 0.0, -0.04]
    translation, rotation = pose_change(start, moved)
    assert translation == pytest.approx(0.05)
    assert rotation == pytest.approx(20.0)


def test_the_test_object_weighs_0_1_kg_with_the_same_shape_of_inertia() -> None:
    bottle = load_object("006_mustard_bottle")
    light = bench_object(bottle)
    assert light.mass == MASS and light.friction == 0.6
    np.testing.assert_allclose(light.inertia * bottle.mass / MASS, bottle.inertia)
    np.testing.assert_array_equal(light.com, bottle.com)


class Idle(Stage):
    name = "idle"

    def step(self, context):  # type: ignore[no-untyped-def]
        return StageOutput(Command.torques(np.zeros(context.obs.q.shape[0])), "ok")


@pytest.mark.parametrize(("direction", "settle"), [((0.0, 0.0, 1.0), 0.2), ((-1.0, 0.0, 0.0), 0.1)])
def test_a_free_object_fails_when_the_push_has_moved_it_5_cm(allegro, direction, settle) -> None:
    # Gravity off, nothing touching: x = a t^2 / 2 after the settle, a = 10 m/s^2, so 5 cm
    # take sqrt(2 * 0.05 / 10) = 0.1 s; the check runs every 5 ms control period.
    obj = bench_object(ObjectModel.sphere(0.02, mass=0.3))
    far = np.eye(4)
    far[:3, 3] = [0.5, 0.5, 0.5]
    backend = MujocoBackend(allegro, obj, far)
    push = Push(ACCELERATION * MASS * np.asarray(direction), settle)
    loop = ControlLoop(backend, allegro, obj, Idle(), rate=200.0, observers=[push])
    report = loop.run(settle + 1.0)
    assert push.failed_in == "push" and report.stopped_by.startswith("object moved")
    expected = settle + np.sqrt(2.0 * MAX_TRANSLATION / ACCELERATION)
    assert expected <= push.elapsed <= expected + 0.006
    assert push.translation >= MAX_TRANSLATION and push.rotation_deg < MAX_ROTATION_DEG
    moved = backend.observe().wMo[:3, 3] - far[:3, 3]
    np.testing.assert_allclose(moved / np.linalg.norm(moved), direction, atol=1e-6)


def test_the_load_test_of_a_held_grasp_and_its_errors(allegro) -> None:
    cube = load_object("077_rubiks_cube")
    out = run_load_test(TrialSpec(allocator="qp", allocator_params={"mu": 0.6}), allegro, cube)
    assert out["held"] and out["failed_direction"] == "" and len(out["directions"]) == 6
    assert out["translation_m"] < MAX_TRANSLATION and out["rotation_deg"] < MAX_ROTATION_DEG
    assert [d.direction for d in out["directions"]] == ["+x", "-x", "+y", "-y", "+z", "-z"]
    with pytest.raises(ConfigError, match="gravity off"):
        run_load_test(TrialSpec(gravity=True), allegro, cube)


def test_dexgraspbench_study_rows_and_summary(tmp_path) -> None:
    from wholehand.studies import get_study, run_study

    result = run_study(
        get_study("dexgraspbench"), "tiny", tmp_path, executor="serial", progress=False
    )
    rows = {r["method"]: r for r in result.rows}
    assert set(rows) == {"qp", "feedforward"}
    for row in rows.values():
        assert row["kind"] == "load_test" and not row["error"]
        assert row["held"] == (row["directions_passed"] == 6)
        assert row["held"] == (row["failed_in"] == "")
    groups = {g["method"]: g for g in result.summary["groups"]}
    for method, row in rows.items():
        assert groups[method]["success"] == float(row["held"])
        assert groups[method]["failed_in_settle"] + groups[method]["failed_in_push"] == int(
            not row["held"]
        )
    assert (tmp_path / "dexgraspbench.png").stat().st_size > 0


def test_a_row_names_a_diverged_simulation_by_its_warnings() -> None:
    from wholehand.trials.outcome import DIVERGED_PREFIX, sim_warnings_error

    assert sim_warnings_error({"bad_qacc": 0, "bad_qpos": 0, "step_retries": 3}) == ""
    for key in ("bad_qacc", "bad_qpos"):
        error = sim_warnings_error({key: 1})
        assert error.startswith(DIVERGED_PREFIX) and key in error
