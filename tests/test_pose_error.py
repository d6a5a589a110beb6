"""Object-pose error (paper Sec. IV-B-2): the offset, where it applies, and the pose-error study."""

from __future__ import annotations

import csv
import json

import numpy as np
import pinocchio as pin
import pytest

from wholehand.errors import ConfigError
from wholehand.models.object_catalogue import load_object
from wholehand.studies import get_study, run_study
from wholehand.studies.base import TINY_PROTOCOL
from wholehand.trials.trial import TrialSpec, pose_error_offset, run_trial

ERROR = {"rot_deg": 30.0, "trans_mm": 5.0, "seed": 3}


def _spec(**kw) -> TrialSpec:
    return TrialSpec(theta_deg=0.0, protocol_params=dict(TINY_PROTOCOL), **kw)


def test_offset_is_deterministic_per_seed_and_has_the_asked_size():
    T = pose_error_offset(ERROR)
    assert T is not None
    np.testing.assert_array_equal(T, pose_error_offset(dict(ERROR)))
    other = pose_error_offset({**ERROR, "seed": 4})
    assert not np.allclose(T, other)
    assert np.rad2deg(np.linalg.norm(pin.log3(T[:3, :3]))) == pytest.approx(30.0)
    assert 1e3 * np.linalg.norm(T[:3, 3]) == pytest.approx(5.0)
    np.testing.assert_array_equal(T[3], [0.0, 0.0, 0.0, 1.0])
    # Same seed, smaller level: same axis and direction, scaled.
    half = pose_error_offset({"rot_deg": 15.0, "trans_mm": 2.5, "seed": 3})
    np.testing.assert_allclose(2 * half[:3, 3], T[:3, 3])
    np.testing.assert_allclose(2 * pin.log3(half[:3, :3]), pin.log3(T[:3, :3]))
    # About a centre c: the same rotation, c moves by exactly the translation, and a point on
    # the rotation axis through c moves by the translation too.
    c = np.array([0.01, -0.07, 0.02])
    Tc = pose_error_offset(ERROR, centre=c)
    np.testing.assert_allclose(Tc[:3, :3], T[:3, :3])
    np.testing.assert_allclose(Tc[:3, :3] @ c + Tc[:3, 3] - c, T[:3, 3], atol=1e-15)
    axis = pin.log3(T[:3, :3])
    on_axis = c + 0.05 * axis / np.linalg.norm(axis)
    np.testing.assert_allclose(Tc[:3, :3] @ on_axis + Tc[:3, 3] - on_axis, T[:3, 3], atol=1e-15)
    assert pose_error_offset({}) is None
    assert pose_error_offset({"rot_deg": 0, "trans_mm": 0, "seed": 9}) is None
    with pytest.raises(ConfigError, match="unknown"):
        pose_error_offset({"rot": 1.0})
    with pytest.raises(ConfigError, match=">= 0"):
        pose_error_offset({"rot_deg": -1.0})


def test_offset_goes_to_the_controller_only(monkeypatch):
    """The estimator gets wMo_true @ T; grasp loss and the record keep the true pose."""
    from wholehand_plugins.mesh_sdf import MeshSDFEstimator

    from wholehand.loop.control_loop import Observer
    from wholehand.loop.grasp_loss import GraspLossCheck

    seen: dict[str, list[np.ndarray]] = {"estimator": [], "truth": [], "loss": []}
    estimate, held = MeshSDFEstimator.estimate, GraspLossCheck.held

    def spy_estimate(self, kinematics, wMo, stamp=0.0):
        seen["estimator"].append(wMo.copy())
        return estimate(self, kinematics, wMo, stamp)

    def spy_held(self, kinematics, wMo):
        seen["loss"].append(wMo.copy())
        return held(self, kinematics, wMo)

    class Truth(Observer):
        def on_cycle(self, cycle):
            seen["truth"].append(cycle.truth.wMo.copy())

    monkeypatch.setattr(MeshSDFEstimator, "estimate", spy_estimate)
    monkeypatch.setattr(GraspLossCheck, "held", spy_held)
    record = run_trial(_spec(pose_error=ERROR), observers=[Truth()])
    T = pose_error_offset(ERROR, load_object("077_rubiks_cube").com)
    a = record.arrays()
    # The loop's preload, before the first cycle, puts the object at the origin, not the truth.
    preload = seen["estimator"].pop(0)
    np.testing.assert_array_equal(preload, np.eye(4))
    assert len(seen["estimator"]) == len(seen["loss"]) == len(seen["truth"]) == a["t"].size > 0
    for given, true, loss_pose, p in zip(
        seen["estimator"], seen["truth"], seen["loss"], a["p_object"], strict=True
    ):
        np.testing.assert_allclose(given, true @ T)
        np.testing.assert_array_equal(loss_pose, true)  # true-pose grasp-loss criterion
        np.testing.assert_array_equal(p, true[:3, 3])  # the record holds the true pose


def test_pose_error_changes_the_run_and_zero_error_changes_nothing():
    base = run_trial(_spec()).arrays()
    zero = run_trial(_spec(pose_error={"rot_deg": 0.0, "trans_mm": 0.0, "seed": 3})).arrays()
    for key in ("tau", "p_object", "n_contacts", "contact_p", "contact_f", "held"):
        np.testing.assert_array_equal(zero[key], base[key], err_msg=key)
    perturbed = run_trial(_spec(pose_error=ERROR)).arrays()
    assert perturbed["tau"].shape[1] == base["tau"].shape[1]
    n = min(len(base["tau"]), len(perturbed["tau"]))
    assert not np.allclose(perturbed["tau"][:n], base["tau"][:n])


def test_feedforward_initialises_on_the_perturbed_pose(monkeypatch):
    """The ground-truth contacts move with wMo_given @ inv(wMo_true) before the allocation."""
    from wholehand.allocation.baselines import FixedAllocationBaseline

    inits = []
    initialise = FixedAllocationBaseline.initialise

    def spy(self, contacts, kinematics, p_com):
        inits.append((contacts, np.array(p_com)))
        return initialise(self, contacts, kinematics, p_com)

    monkeypatch.setattr(FixedAllocationBaseline, "initialise", spy)
    base = run_trial(_spec(allocator="feedforward")).arrays()
    perturbed = run_trial(_spec(allocator="feedforward", pose_error=ERROR)).arrays()
    (c0, com0), (c1, com1) = inits
    assert len(c0) == len(c1) > 0
    # The initial state is the stored grasp, so wMo_true is the same in both runs.
    from wholehand.grasps.store import load_grasps
    from wholehand.models.hand import load_hand

    hand = load_hand("allegro_right")
    wMo = load_grasps("allegro_right", "077_rubiks_cube")[0].object_pose(hand.wMb)
    M = wMo @ pose_error_offset(ERROR, load_object("077_rubiks_cube").com) @ np.linalg.inv(wMo)
    np.testing.assert_allclose(c1.p_world, c0.p_world @ M[:3, :3].T + M[:3, 3], atol=1e-9)
    np.testing.assert_allclose(c1.n_world, c0.n_world @ M[:3, :3].T, atol=1e-9)
    np.testing.assert_allclose(com1, M[:3, :3] @ com0 + M[:3, 3], atol=1e-9)
    # The held feedforward torque J^T f differs from the unperturbed one, and stays constant.
    assert not np.allclose(perturbed["tau"][0], base["tau"][0])
    np.testing.assert_array_equal(
        perturbed["tau"], np.broadcast_to(perturbed["tau"][0], perturbed["tau"].shape)
    )


def test_tiny_pose_error_study_writes_its_outputs(tmp_path):
    study = get_study("pose-error")
    full = study.jobs("full", seed=0)
    # 50 grasps x (1 + 3 levels x 5 directions) x (3 thresholds + feedforward).
    assert len(full) == 50 * 16 * 4
    assert {j.spec.theta_deg for j in full} == {0.0}
    assert {j.spec.estimator_params.get("d_thresh") for j in full} == {None, 0.005, 0.01, 0.02}
    result = run_study(study, "tiny", tmp_path, executor="serial", progress=False)
    with open(result.csv_path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(study.jobs("tiny", 0)) == 4
    assert all(r["error"] == "" for r in rows)
    assert {json.loads(r["pose_error"]).get("rot_deg") for r in rows} == {None, 30.0}
    summary = json.loads(result.summary_path.read_text())
    assert summary["n_trials"] == 4 and summary["n_errors"] == 0
    assert {(g["method"], g["d_thresh"], g["rot_deg"]) for g in summary["groups"]} == {
        ("qp", 0.01, 0.0),
        ("qp", 0.01, 30.0),
        ("feedforward", None, 0.0),
        ("feedforward", None, 30.0),
    }
    assert all("se" in g and 0.0 <= g["success"] <= 1.0 for g in summary["groups"])
    assert result.plot_path.read_bytes()[:4] == b"\x89PNG"
