"""The MuJoCo step guard: a failed contact solve is taken again, a healthy step is untouched."""

from __future__ import annotations

import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest
from wholehand_plugins.mujoco.backend import MujocoBackend
from wholehand_plugins.mujoco.scene_options import HAND_BIT
from wholehand_plugins.mujoco.step_guard import MAX_SPEED

from wholehand.backends.command import Command
from wholehand.models.object_catalogue import load_object
from wholehand.models.objects import ObjectModel

STATE = mujoco.mjtState.mjSTATE_INTEGRATION
FIXTURE = Path(__file__).parent / "data" / "failed_contact_solve.npz"
"""The state before a step whose Newton solve fails: perturbation study (full, seed 0) trial 32,
``qp`` on 006_mustard_bottle grasp 0 at 30 deg, t = 10.435 s (MuJoCo 4.0.0). Without the guard
this trial ends in ``bad_qacc`` 10 ms later."""


@pytest.fixture(scope="module")
def bottle_scene(allegro):
    backend = MujocoBackend(allegro, load_object("006_mustard_bottle"))
    state = np.load(FIXTURE)["state"]
    return backend, state


def speed(data) -> float:
    return float(np.abs(data.qvel).max())


def test_the_recorded_state_makes_a_plain_step_fail(bottle_scene):
    """The ground truth the other tests stand on: from this state, MuJoCo's own step leaves
    joint speeds of thousands of rad/s (its Newton solve fails on a frictional contact between
    the middle and ring fingers' boxes)."""
    backend, state = bottle_scene
    m, d = backend.model, mujoco.MjData(backend.model)
    mujoco.mj_setState(m, d, state, STATE)
    mujoco.mj_step(m, d)
    assert speed(d) > MAX_SPEED


def test_a_failed_step_is_taken_again_with_frictionless_hand_hand_contacts(bottle_scene):
    backend, state = bottle_scene
    m, d = backend.model, backend.data
    condim = m.geom_condim.copy()
    mujoco.mj_setState(m, d, state, STATE)
    backend.step(m.opt.timestep)
    counts = backend.warnings()
    assert counts["step_retries"] == 1 and counts["step_retries_failed"] == 0
    assert counts["bad_qacc"] == 0
    assert speed(d) < 1.0  # calm, as in the cycles before
    np.testing.assert_array_equal(m.geom_condim, condim)  # the model is left as it was
    # The contacts of the retried step: hand-hand ones frictionless, hand-object ones not.
    hand = m.geom_contype == HAND_BIT
    pairs = [(int(c.geom1), int(c.geom2), int(c.dim)) for c in d.contact]
    self_dims = {dim for g1, g2, dim in pairs if hand[g1] and hand[g2]}
    object_dims = {dim for g1, g2, dim in pairs if hand[g1] != hand[g2]}
    assert self_dims == {1} and object_dims == {3}
    # ... and the retried step is exactly MuJoCo's step of that model.
    reference = mujoco.MjData(m)
    mujoco.mj_setState(m, reference, state, STATE)
    m.geom_condim[hand] = 1
    try:
        mujoco.mj_step(m, reference)
    finally:
        m.geom_condim[:] = condim
    np.testing.assert_array_equal(d.qpos, reference.qpos)
    np.testing.assert_array_equal(d.qvel, reference.qvel)


def test_a_healthy_simulation_is_bit_identical_to_plain_mujoco_steps(allegro):
    backend = MujocoBackend(allegro, ObjectModel.sphere(0.03, mass=0.1))
    tau = np.where(np.isin(allegro.joint_names, ["joint_0.0", "joint_4.0", "joint_8.0"]), 0, 0.1)
    backend.apply(Command(tau))
    m = backend.model
    reference = mujoco.MjData(m)
    mujoco.mj_setState(m, reference, _state(m, backend.data), STATE)
    backend.step(0.3)
    mujoco.mj_step(m, reference, nstep=300)
    np.testing.assert_array_equal(backend.data.qpos, reference.qpos)
    np.testing.assert_array_equal(backend.data.qvel, reference.qvel)
    assert not any(backend.warnings().values())


def test_a_step_that_fails_again_is_counted_and_mujoco_resets_once(allegro):
    """An applied force of 1e20 N makes every step diverge: the retry fails too, is counted,
    and MuJoCo's own bad_qacc count says one divergence, not two."""
    backend = MujocoBackend(allegro, ObjectModel.sphere(0.03, mass=0.1))
    backend.data.qfrc_applied[0] = 1e20
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        backend.step(backend.timestep)
    counts = backend.warnings()
    assert counts["step_retries"] == 1 and counts["step_retries_failed"] == 1
    assert counts["bad_qacc"] == 1
    backend.reset(allegro.neutral(), backend.observe().wMo)
    assert backend.warnings()["step_retries"] == 0


def _state(m, d):
    out = np.empty(mujoco.mj_stateSize(m, STATE))
    mujoco.mj_getState(m, d, out, STATE)
    return out


def test_an_object_spinning_free_is_not_mistaken_for_a_failed_solve(allegro):
    """A snatch tears the object out of the hand spinning at up to ~110 rad/s: a legitimate
    state, left alone; a hand joint that fast is a failed solve and is retried."""
    backend = MujocoBackend(allegro, ObjectModel.sphere(0.03, mass=0.1))
    m, d = backend.model, backend.data
    obj = m.body("object")
    spin = int(m.jnt_dofadr[obj.jntadr[0]]) + 5  # the object's turn about z
    d.qvel[spin] = 300.0
    backend.step(m.opt.timestep)
    assert backend.warnings()["step_retries"] == 0
    assert d.qvel[spin] == pytest.approx(300.0, rel=1e-3)  # far from the hand: it keeps turning
    d.qvel[:] = 0.0
    d.qvel[m.joint("joint_1.0").dofadr[0]] = 300.0
    backend.step(m.opt.timestep)
    assert backend.warnings()["step_retries"] == 1
