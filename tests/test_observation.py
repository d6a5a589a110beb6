"""Timestamped observations: the joint history, the observation filters, contacts carried with
their links to a newer configuration, and the latency path of force regulation."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from wholehand.backends.observation import JointHistory, Observation, check_observation
from wholehand.contacts.base import ContactSet
from wholehand.errors import ConfigError, ObservationError
from wholehand.loop.control_loop import Observer
from wholehand.loop.filters import (
    ConstantPoseError,
    PoseDropout,
    PoseNoise,
    PosePredictor,
    PoseTracker,
)
from wholehand.models.kinematics import HandKinematics
from wholehand.trials.trial import TrialSpec, run_trial, tracking_filters

TINY = {"settle_time": 0.1, "load_duration": 0.05, "rotation_time": 0.2}


def _pose(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return pin.exp6(pin.Motion(rng.normal(size=6) * 0.3)).homogeneous


def test_history_is_exact_at_samples_linear_between_and_refuses_older_stamps():
    h = JointHistory(n_q=2, capacity=4)
    with pytest.raises(ObservationError, match="no joint sample"):
        h.at(0.0)
    poses = [_pose(i) for i in range(6)]
    for i in range(6):
        h.push(0.01 * i, np.array([i, -2.0 * i]), poses[i])
    assert len(h) == 4 and h.oldest_stamp == pytest.approx(0.02)
    q, wMb = h.at(0.03)
    np.testing.assert_array_equal(q, [3.0, -6.0])
    np.testing.assert_array_equal(wMb, poses[3])
    q, wMb = h.at(0.0325)
    np.testing.assert_allclose(q, [3.25, -6.5])
    # On the SE(3) geodesic: a quarter of the relative motion from sample 3 to sample 4.
    rel = pin.log6(pin.SE3(poses[3]).actInv(pin.SE3(poses[4]))).vector
    expected = poses[3] @ pin.exp6(pin.Motion(0.25 * rel)).homogeneous
    np.testing.assert_allclose(wMb, expected, atol=1e-12)
    np.testing.assert_array_equal(h.at(1.0)[0], [5.0, -10.0])  # newer: the newest sample
    with pytest.raises(ObservationError, match="older than the joint history"):
        h.at(0.015)
    with pytest.raises(ObservationError, match="go back in time"):
        h.push(0.01, np.zeros(2), np.eye(4))
    with pytest.raises(ConfigError, match="capacity"):
        JointHistory(2, capacity=0)


@pytest.mark.parametrize("pushed", range(1, 10))
def test_history_brackets_every_stamp_at_every_fill_of_the_ring(pushed):
    h = JointHistory(n_q=1, capacity=4)
    stamps = [0.01 * i * (1 + 0.1 * i) for i in range(pushed)]  # uneven spacing
    for i, t in enumerate(stamps):
        h.push(t, np.array([float(i)]), np.eye(4))
    kept = stamps[-4:]
    for t in np.linspace(kept[0], kept[-1] + 0.01, 23):
        k = max(i for i, s in enumerate(kept) if s <= t)  # the newest sample at or before t
        value = float(pushed - len(kept) + k)  # q of sample k is its index
        if k + 1 < len(kept) and t > kept[k]:
            value += (t - kept[k]) / (kept[k + 1] - kept[k])
        assert h.at(t)[0][0] == pytest.approx(value, abs=1e-12), t


def _obs(q=(0.1, 0.2), wMo=None, t=0.0, stamp_object=None, history=None):
    history = history or JointHistory(2)
    if not len(history) or history.newest_stamp < t:
        history.push(t, np.asarray(q, float), np.eye(4))
    return Observation(
        np.asarray(q, float),
        np.zeros(2),
        np.eye(4),
        t,
        np.eye(4) if wMo is None else wMo,
        t if stamp_object is None else stamp_object,
        history,
    )


def test_check_observation_names_the_field():
    check_observation(_obs(), 2, 2)
    bad = np.eye(4)
    bad[0, 0] = 2.0
    good = _obs()
    short = Observation(np.zeros(3), good.dq, good.wMb, 0.0, good.wMo, 0.0, good.history)
    for obs, match in (
        (_obs(q=(np.nan, 0.0)), "q contains NaN"),
        (short, r"q has shape \(3,\)"),
        (_obs(wMo=bad), "wMo"),
        (_obs(stamp_object=np.inf), "stamp_object"),
    ):
        with pytest.raises(ObservationError, match=match):
            check_observation(obs, 2, 2)


def _track(filt, steps=40, dt=0.005):
    """Feed a moving object (x = t) through a filter; (t, seen x, seen stamp) per cycle."""
    history = JointHistory(2)
    out = []
    for k in range(steps):
        t = k * dt
        wMo = np.eye(4)
        wMo[0, 3] = t
        seen = filt.apply(_obs(wMo=wMo, t=t, history=history), t)
        out.append((t, None if seen.wMo is None else seen.wMo[0, 3], seen.stamp_object))
    return out


def test_tracker_delivers_each_frame_late_and_keeps_it_until_the_next():
    rows = _track(PoseTracker(rate_hz=30.0, latency_s=0.033), steps=50)
    for t, x, stamp in rows:
        assert x == pytest.approx(stamp)  # the pose is the one of its own stamp
        assert t - stamp < 1 / 30 + 0.033 + 0.005 + 1e-9  # never older than a frame + latency
    stamps = sorted({s for _, _, s in rows})
    # Frames on the first cycle at or after k/30 s: 0, 35, 70, 100, 135, 170, 200 ms.
    np.testing.assert_allclose(stamps, [0.0, 0.035, 0.07, 0.1, 0.135, 0.17, 0.2], atol=1e-12)
    delivered = {s: min(t for t, _, st in rows if st == s) for s in stamps}
    for s in stamps[1:]:
        assert delivered[s] == pytest.approx(s + 0.035)  # first cycle at or after s + 33 ms
    exact = _track(PoseTracker(rate_hz=200.0, latency_s=0.0))
    assert all(x == pytest.approx(t) and st == pytest.approx(t) for t, x, st in exact)
    with pytest.raises(ConfigError, match="rate_hz"):
        PoseTracker(rate_hz=0.0)
    with pytest.raises(ConfigError, match="latency_s"):
        PoseTracker(latency_s=-1.0)


def _screw(t: float) -> np.ndarray:
    """The pose at time t [s] of an object moving at 0.3 m/s and turning at 2 rad/s (constant
    velocities of its origin and about it, world axes)."""
    M = np.eye(4)
    M[:3, :3] = pin.exp3(np.array([0.0, 2.0 * t, 0.0])) @ pin.rpy.rpyToMatrix(0.1, 0.2, 0.3)
    M[:3, 3] = np.array([0.3, -0.1, 0.05]) * t / np.linalg.norm([0.3, -0.1, 0.05]) * 0.3
    return M


def test_prediction_cancels_a_trackers_latency_at_constant_velocity():
    """Behind a 30 Hz, 33 ms tracker, the predicted pose of an object at constant velocity is
    its true pose at the joint state's time, stamped with that time, once two frames came;
    past the horizon it stops; across a gap there is no velocity."""
    tracker, predictor = PoseTracker(30.0, 0.033), PosePredictor(horizon_s=0.1)
    history = JointHistory(2)
    seen_stamps = []
    for k in range(60):
        t = k * 0.005
        seen = predictor.apply(tracker.apply(_obs(wMo=_screw(t), t=t, history=history), t), t)
        seen_stamps.append(seen.stamp_object)
        if t >= 0.035 + 0.033 + 1e-9:  # the second frame has arrived
            np.testing.assert_allclose(seen.wMo, _screw(t), atol=1e-12)
            assert seen.stamp_object == pytest.approx(t)
    assert seen_stamps[0] == 0.0  # one frame: as the tracker gives it
    # The horizon: a pose 0.25 s old is carried 0.1 s, no further.
    slow = PosePredictor(horizon_s=0.1)
    for stamp in (0.0, 0.02):
        slow.apply(_obs(wMo=_screw(stamp), t=stamp), stamp)
    late = slow.apply(_obs(wMo=_screw(0.02), t=0.27, stamp_object=0.02), 0.27)
    assert late.stamp_object == pytest.approx(0.12)
    np.testing.assert_allclose(late.wMo, _screw(0.12), atol=1e-12)
    # Two poses 0.5 s apart (a dropout) give no velocity: the newest pose as it is.
    gap = PosePredictor(max_gap_s=0.2)
    for stamp in (0.0, 0.5):
        out = gap.apply(_obs(wMo=_screw(stamp), t=stamp + 0.03, stamp_object=stamp), 0.6)
    np.testing.assert_array_equal(out.wMo, _screw(0.5))
    with pytest.raises(ConfigError, match="horizon_s must be finite and > 0"):
        PosePredictor(horizon_s=0.0)


def test_dropout_holds_the_last_pose_with_its_stamp():
    rows = _track(PoseDropout([(0.05, 0.05)]))
    for t, x, stamp in rows:
        expect = 0.045 if 0.05 - 1e-9 <= t < 0.1 - 1e-9 else t
        assert x == pytest.approx(expect) and stamp == pytest.approx(expect)
    start = _track(PoseDropout([(0.0, 0.02)]), steps=6)
    assert [x is None for _, x, _ in start] == [True] * 4 + [False] * 2
    with pytest.raises(ConfigError, match="interval"):
        PoseDropout([(0.0, -1.0)])


def test_noise_is_seeded_per_frame_and_of_the_asked_size():
    a = _track(PoseNoise(trans_mm=2.0, seed=1), steps=400)
    b = _track(PoseNoise(trans_mm=2.0, seed=1), steps=400)
    assert a == b
    err = np.array([x - t for t, x, _ in a])
    assert 1.6e-3 < err.std() < 2.4e-3 and abs(err.mean()) < 4e-4
    # One draw per new stamp: behind a 30 Hz tracker, the noise changes only with the frame.
    tracked = PoseTracker(30.0, 0.0)
    noisy = PoseNoise(trans_mm=2.0, seed=1)
    history = JointHistory(2)
    per_stamp: dict[float, set[float]] = {}
    for k in range(60):
        t = 0.005 * k
        seen = noisy.apply(tracked.apply(_obs(t=t, history=history), t), t)
        per_stamp.setdefault(seen.stamp_object, set()).add(float(seen.wMo[0, 3]))
    assert len(per_stamp) > 5 and all(len(v) == 1 for v in per_stamp.values())
    with pytest.raises(ConfigError, match="trans_mm"):
        PoseNoise(trans_mm=-1.0)


def test_constant_error_and_the_spec_builds_filters_in_order():
    T = _pose(3)
    seen = ConstantPoseError(T).apply(_obs(wMo=_pose(4)), 0.0)
    np.testing.assert_array_equal(seen.wMo, _pose(4) @ T)
    filters = tracking_filters(
        {"rate_hz": 30, "latency_s": 0.033, "noise_mm": 1.0, "dropouts": [[1.0, 0.2]]}
    )
    assert [type(f).__name__ for f in filters] == ["PoseTracker", "PoseNoise", "PoseDropout"]
    assert tracking_filters({}) == []
    with pytest.raises(ConfigError, match="unknown keys"):
        tracking_filters({"rate": 30})
    with pytest.raises(ConfigError, match="rate_hz must be a number"):
        tracking_filters({"rate_hz": "fast"})
    with pytest.raises(ConfigError, match="dropouts must be"):
        tracking_filters({"dropouts": [1.0]})


def test_contacts_carried_with_their_links_match_the_frames(allegro):
    """A contact fixed on its link: its world point at a new q is that link's frame motion."""
    rng = np.random.default_rng(0)
    then, now = HandKinematics(allegro), HandKinematics(allegro)
    q0 = allegro.neutral() + 0.2 * rng.uniform(size=allegro.nq)
    q1 = q0 + 0.1 * rng.standard_normal(allegro.nq)
    then.update(q0)
    now.update(q1)
    links = np.array([allegro.link_index(n) for n in ("link_3.0_tip", "link_14.0", "palm_link")])
    p = rng.normal(scale=0.05, size=(3, 3))
    n = rng.normal(size=(3, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    contacts = ContactSet(
        p,
        n,
        links,
        np.zeros(3),
        np.asarray(allegro.link_actuated),
        np.asarray(allegro.link_fingertip),
    )
    moved = contacts.in_joint_frames(then).moved_to(now)
    for i, link in enumerate(links):
        name = allegro.link_names[link]
        M = now.frame_pose(name) @ np.linalg.inv(then.frame_pose(name))
        np.testing.assert_allclose(moved.p_world[i], M[:3, :3] @ p[i] + M[:3, 3], atol=1e-12)
        np.testing.assert_allclose(moved.n_world[i], M[:3, :3] @ n[i], atol=1e-12)
    same = contacts.in_joint_frames(then).moved_to(then)
    np.testing.assert_allclose(same.p_world, p, atol=1e-14)
    assert moved.select(np.array([True, False, True])).p_joint.shape == (2, 3)
    with pytest.raises(ConfigError, match="in_joint_frames"):
        contacts.moved_to(now)
    with pytest.raises(ConfigError, match="together"):
        ContactSet(
            p, n, links, np.zeros(3), contacts.link_actuated, contacts.link_fingertip, p_joint=p
        )


class KinematicsSpy(Observer):
    """Checks each cycle that the contacts were estimated at q(stamp_object)."""

    def __init__(self):
        self.lags, self.checked = [], 0

    def on_cycle(self, cycle):
        obs = cycle.context.obs
        self.lags.append(obs.stamp_q - obs.stamp_object)
        then = cycle.context.kinematics_object
        q_then, _ = obs.history.at(obs.stamp_object)
        np.testing.assert_array_equal(then.q, q_then)
        self.checked += 1


def test_latency_run_estimates_at_the_pose_stamp_and_differs_from_current(allegro):
    spec = TrialSpec(
        theta_deg=0.0, protocol_params=TINY, tracking={"rate_hz": 30.0, "latency_s": 0.033}
    )
    spy = KinematicsSpy()
    at_stamp = run_trial(spec, allegro, observers=[spy])
    a = at_stamp.arrays()
    assert spy.checked == len(a["t"]) and max(spy.lags) > 0.033
    np.testing.assert_allclose(a["t"] - a["stamp_object"], spy.lags)  # recorded pose age
    current = run_trial(TrialSpec(**{**spec.__dict__, "estimate_at": "current"}), allegro)
    exact = run_trial(TrialSpec(theta_deg=0.0, protocol_params=TINY), allegro)
    for rec in (at_stamp, current, exact):
        assert rec.held_throughout
    assert not np.array_equal(at_stamp.arrays()["tau"], current.arrays()["tau"])
    assert not np.array_equal(at_stamp.arrays()["tau"], exact.arrays()["tau"])
    # With an exact tracker (200 Hz, no latency) the stamps agree and nothing changes.
    same = run_trial(
        TrialSpec(theta_deg=0.0, protocol_params=TINY, tracking={"rate_hz": 200.0}), allegro
    )
    np.testing.assert_array_equal(same.arrays()["tau"], exact.arrays()["tau"])


def test_the_compiled_check_agrees_with_check_pose():
    """The fast path accepts exactly the poses :func:`check_pose` accepts."""
    from wholehand.models.poses import check_pose

    rng = np.random.default_rng(5)
    cases = []
    for _ in range(30):
        M = _pose(int(rng.integers(1000)))
        cases.append(M)
        for scale in (1 + 1e-8, 1 + 1e-5):
            S = M.copy()
            S[:3, :3] *= scale
            cases.append(S)
        R = M.copy()
        R[:3, 0] *= -1.0  # a reflection
        cases.append(R)
        L = M.copy()
        L[3, 1] = 1e-9
        cases.append(L)
    for M in cases:
        try:
            check_pose(M)
            expected = True
        except ConfigError:
            expected = False
        try:
            check_observation(_obs(wMo=M), 2, 2)
            got = True
        except ObservationError:
            got = False
        assert got == expected, M


def test_is_rigid_against_poses_of_known_validity():
    from wholehand.models.poses import check_pose, is_rigid

    M = _pose(7)
    assert is_rigid(M) and check_pose(M) is not None
    near = M.copy()
    near[:3, :3] *= 1 + 1e-8  # within the 1e-6 orthonormality tolerance
    assert is_rigid(near)
    bad = {
        "scaled": (1 + 1e-5, None, "proper rotation"),
        "reflected": (None, (slice(0, 3), 0), "proper rotation"),
        "last row": (None, (3, 1), "last row"),
        "nan": (None, (1, 3), "NaN"),
    }
    for what, (scale, index, message) in bad.items():
        B = M.copy()
        if scale is not None:
            B[:3, :3] *= scale
        elif what == "reflected":
            B[index] *= -1.0
        elif what == "last row":
            B[index] = 1e-9
        else:
            B[index] = np.nan
        assert not is_rigid(B), what
        with pytest.raises(ConfigError, match=message):
            check_pose(B, "wMb")
