"""Grasp synthesis by optimisation: the energy's gradient, the annealing, the validated grasps."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from wholehand.cli.main import main
from wholehand.grasps.optimized import OPEN_ANGLE, closing_torques
from wholehand.grasps.store import Grasp, load_grasps
from wholehand.grasps.synthesis import GraspSynthesizer, SynthesisState
from wholehand.grasps.synthesis_params import SynthesisParams
from wholehand.models.kinematics import HandKinematics
from wholehand.models.object_catalogue import load_object
from wholehand.models.objects import ObjectModel
from wholehand.reaching.pregrasp import OPEN_DISTANCE, plan_pregrasp


@pytest.fixture(scope="module")
def ball() -> ObjectModel:
    return ObjectModel.sphere(0.035, mass=0.1, sdf_spacing=0.002)


def _near_surface_states(hand, obj) -> list[SynthesisState]:
    """Three states whose contacts lie within 2 cm of the surface, inside the SDF's grid
    (outside it the SDF is a bound, not a distance): ends of short optimisations."""
    params = SynthesisParams(iterations=150, w_self=0.0)  # inputs only: the seeds' own ends
    syn = GraspSynthesizer(hand, obj, hand.config.grasp_styles["power"], params=params)
    states = []
    for r in syn.optimise(8, seed=0):
        state = SynthesisState(r.oMb, r.q[syn.act], r.contacts)
        syn.evaluate(state, gradient=False)
        assert state.energy is not None
        if state.energy.distance < 0.02 * len(r.contacts):
            states.append(state)
    assert len(states) >= 3
    return states[:3]


def _numeric_gradient(syn: GraspSynthesizer, state: SynthesisState, h: tuple) -> dict:
    """Central differences with steps ``h`` = (translation [m], rotation [rad], joints
    [rad])."""
    h_t, h_w, h_a = h

    def energy(oMb: np.ndarray, a: np.ndarray) -> float:
        return syn.evaluate(SynthesisState(oMb, a, state.contacts), gradient=False).total

    out: dict[str, list[float]] = {"t": [], "w": [], "a": []}
    for i in range(3):
        plus, minus = state.oMb.copy(), state.oMb.copy()
        plus[i, 3] += h_t
        minus[i, 3] -= h_t
        out["t"].append((energy(plus, state.a) - energy(minus, state.a)) / (2 * h_t))
        plus, minus = state.oMb.copy(), state.oMb.copy()
        plus[:3, :3] = Rotation.from_rotvec(h_w * np.eye(3)[i]).as_matrix() @ plus[:3, :3]
        minus[:3, :3] = Rotation.from_rotvec(-h_w * np.eye(3)[i]).as_matrix() @ minus[:3, :3]
        out["w"].append((energy(plus, state.a) - energy(minus, state.a)) / (2 * h_w))
    for k in range(state.a.size):
        plus, minus = state.a.copy(), state.a.copy()
        plus[k] += h_a
        minus[k] -= h_a
        out["a"].append((energy(state.oMb, plus) - energy(state.oMb, minus)) / (2 * h_a))
    return {k: np.array(v) for k, v in out.items()}


class ExactSphere:
    """The signed distance of a sphere, analytic: a field without interpolation cells."""

    spacing = 0.002

    def __init__(self, radius: float) -> None:
        self.radius = radius

    def query(self, p: np.ndarray) -> np.ndarray:
        return np.linalg.norm(p, axis=1) - self.radius

    def nearest_below(self, p: np.ndarray, threshold: float) -> np.ndarray:
        return np.flatnonzero(self.query(p) < threshold)

    def near_spheres(self, c: np.ndarray, r: np.ndarray, threshold: float) -> np.ndarray:
        return self.query(c) - r < threshold

    def query_with_gradient(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        norm = np.linalg.norm(p, axis=1)
        return norm - self.radius, p / norm[:, None]


DISTANCES = {"w_dis": 1.0, "w_fc": 0.0, "w_align": 0.0, "w_pen": 1.0, "w_table": 1.0}
NORMALS = {"w_dis": 0.0, "w_fc": 1.0, "w_align": 1.0, "w_pen": 0.0, "w_table": 0.0}


@pytest.mark.parametrize(
    ("weights", "exact", "tol"),
    [(DISTANCES, True, 1e-4), (NORMALS, True, 5e-3), (DISTANCES, False, 0.05)],
    ids=["distances", "normals", "distances-on-the-grid"],
)
def test_the_energy_gradient_matches_finite_differences(allegro, ball, weights, exact, tol):
    """On an exact sphere the gradient is the energy's up to the object normal's derivatives,
    which the synthesiser takes by central differences over half a grid cell. On the SDF grid
    the distance terms use its unit gradient, where the interpolant's own slope is a few per
    cent off one. (The grid's normals are piecewise, so differences are no reference there.)"""
    syn = GraspSynthesizer(
        allegro,
        ball,
        allegro.config.grasp_styles["power"],
        table_up=[0.0, 0.0, 1.0],
        params=SynthesisParams(**weights),
    )
    if exact:
        syn.sdf = ExactSphere(0.035)  # type: ignore[assignment]
    for seed, state in enumerate(_near_surface_states(allegro, ball)):
        syn.evaluate(state)
        numeric = _numeric_gradient(syn, state, (1e-6, 1e-6, 1e-6))
        for key in ("t", "w", "a"):
            analytic = state.grad[key]
            scale = max(np.abs(numeric[key]).max(), 1e-9)
            assert np.abs(analytic - numeric[key]).max() <= tol * scale, (seed, key)


SELF = {"w_dis": 0.0, "w_fc": 0.0, "w_align": 0.0, "w_pen": 0.0, "w_table": 0.0, "w_self": 1.0}


def test_the_fingers_apart_gradient_matches_finite_differences(allegro, ball):
    """Configurations with two fingers pressed together (seeded draws within the joint limits
    until the fingers-apart term is positive): its gradient is the energy's."""
    syn = GraspSynthesizer(
        allegro, ball, allegro.config.grasp_styles["power"], params=SynthesisParams(**SELF)
    )
    rng = np.random.default_rng(3)
    base = syn.start(rng)
    found = 0
    for _ in range(400):
        a = rng.uniform(syn.a_lower, syn.a_upper)
        state = SynthesisState(base.oMb, a, base.contacts)
        if syn.evaluate(state).self_penetration < 5e-4:
            continue
        found += 1
        numeric = _numeric_gradient(syn, state, (1e-6, 1e-6, 1e-6))
        scale = np.abs(numeric["a"]).max()
        assert np.abs(state.grad["a"] - numeric["a"]).max() <= 1e-4 * scale
        # Moving the whole hand moves no finger against another: no base gradient.
        for key in ("t", "w"):
            assert np.abs(state.grad[key]).max() < 1e-9 and np.abs(numeric[key]).max() < 1e-8
        if found == 3:
            break
    assert found == 3


def test_the_fingers_apart_term_keeps_optimised_fingers_out_of_each_other(allegro, ball):
    """Without the term, optimised power grasps press fingers into each other; with it (the
    default), the sum of overlaps falls to a fraction."""

    def overlap(params: SynthesisParams) -> float:
        syn = GraspSynthesizer(allegro, ball, allegro.config.grasp_styles["power"], params=params)
        probe = GraspSynthesizer(allegro, ball, allegro.config.grasp_styles["power"])
        total = 0.0
        for r in syn.optimise(6, seed=0):
            state = SynthesisState(r.oMb, r.q[probe.act], r.contacts)
            total += probe.evaluate(state, gradient=False).self_penetration
        return total

    without = overlap(SynthesisParams(iterations=400, w_self=0.0))
    assert without > 0.0
    assert overlap(SynthesisParams(iterations=400)) < 0.25 * without


def test_annealing_brings_the_contacts_to_the_surface_out_of_the_object(allegro, ball):
    syn = GraspSynthesizer(allegro, ball, allegro.config.grasp_styles["power"])
    rng = np.random.default_rng(0)
    starts = [syn.evaluate(syn.start(rng), gradient=False) for _ in range(6)]
    results = syn.optimise(6, seed=0)
    assert sorted(r.start for r in results) == list(range(6))
    assert np.mean([r.energy.total for r in results]) < np.mean([e.total for e in starts])
    best = results[0]
    assert best.energy.distance < 0.01 * len(best.contacts)  # [m], summed over the contacts
    assert best.energy.max_depth < 0.002
    assert np.all(best.q >= allegro.q_lower) and np.all(best.q <= allegro.q_upper)
    # The normals are the sphere's: radial at the contact points.
    kin = HandKinematics(allegro)
    kin.update(best.q, best.oMb)
    s = allegro.samples
    p = kin.transform_points(s.p_joint[best.contacts], s.joint[best.contacts])
    radial = p / np.linalg.norm(p, axis=1, keepdims=True)
    assert np.all(np.einsum("ij,ij->i", radial, best.normals) > 0.95)


def test_closing_torques_squeeze_the_contacts_into_the_object(allegro, ball):
    syn = GraspSynthesizer(
        allegro, ball, allegro.config.grasp_styles["power"], params=SynthesisParams(iterations=50)
    )
    result = syn.optimise(1, seed=1)[0]
    kin = HandKinematics(allegro)
    kin.update(result.q, np.eye(4))
    tau, closing = closing_torques(allegro, kin, result, np.eye(4), ball.com, peak=0.1)
    assert np.abs(tau).max() == pytest.approx(0.1) and closing.any()
    assert not tau[~closing].any() or np.abs(tau[~closing]).max() <= 0.002
    # A small joint motion along the torque moves the contacts into the object on the whole:
    # the work of the inward unit forces is positive (the squeeze's forces push, never pull).
    s = allegro.samples
    p = kin.transform_points(s.p_joint[result.contacts], s.joint[result.contacts])
    J = kin.point_jacobians(s.joint[result.contacts], p)
    work = float(np.einsum("na,nak,k->", -result.normals, J, tau))
    assert work > 0.0


def test_generate_with_the_optimiser_writes_validated_grasps(tmp_path, allegro, capsys):
    code = main(
        [
            "grasps",
            "generate",
            "--method",
            "optimize",
            "--object",
            "077_rubiks_cube",
            "--count",
            "1",
            "--max-candidates",
            "16",
            "--out",
            str(tmp_path),
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    path = tmp_path / "077_rubiks_cube.json"
    assert path.exists(), out
    data = json.loads(path.read_text())
    assert "--method optimize" in data["generator"]["command"]
    (grasp,) = load_grasps(path)
    q = grasp.q_array(allegro)
    assert "thumb" in grasp.extra["fingers"] and len(grasp.extra["fingers"]) >= 3
    assert np.all(q >= allegro.q_lower - 0.05) and np.all(q <= allegro.q_upper + 0.05)
    # The grasp keeps its own open hand, and the reacher's pre-grasp opens toward it, not
    # toward the q_open it is given.
    own = Grasp(0, grasp.oMb, grasp.extra["pregrasp_q"]).q_array(allegro)
    assert np.all(own >= allegro.q_lower) and np.all(own <= allegro.q_upper)
    assert 0.0 < np.abs(own - q).max() <= OPEN_ANGLE + 1e-9
    plan = plan_pregrasp(allegro, load_object("077_rubiks_cube"), grasp, allegro.q_upper)
    assert plan is not None
    share = min(1.0, plan.retreat / OPEN_DISTANCE)
    np.testing.assert_allclose(plan.q_pre, q + share * (own - q), atol=1e-12)


@pytest.mark.parametrize("name", ["allegro_right", "robotis_hx5_d20_right"])
def test_closing_directions_derived_from_the_model_are_the_shipped_ones(name):
    """Each motor that moves a fingertip toward the palm closes that way: on both shipped hands
    the signs agree with their hand.toml's closing torques on every joint it names."""
    from wholehand.models.grasp_styles import derived_close_torque
    from wholehand.models.hand import load_hand

    hand = load_hand(name)
    derived = derived_close_torque(hand)
    shipped = hand.config.grasp_styles["power"].close_torque
    assert shipped and set(shipped) <= set(derived)
    assert all(np.sign(derived[j]) == np.sign(t) for j, t in shipped.items())
    assert all(0.0 < abs(t) <= 0.1 for t in derived.values())


def test_a_hand_without_grasping_tables_gets_optimised_grasps(tmp_path, capsys):
    """The Allegro's hand.toml without its [grasping] tables: the pre-shape generator has
    nothing to close, the optimiser needs nothing more."""
    from wholehand.models.hand_folders import shipped_hands_dir

    text = (shipped_hands_dir() / "allegro_right" / "hand.toml").read_text()
    folder = tmp_path / "bare"
    folder.mkdir()
    bare = text.split("# Power pre-shape")[0].replace('name = "allegro_right"', 'name = "bare"')
    assert "[grasping" not in bare
    (folder / "hand.toml").write_text(bare)
    args = ["grasps", "generate", "--hand", str(folder), "--object", "077_rubiks_cube"]
    args += ["--count", "1", "--max-candidates", "16", "--out", str(tmp_path / "out")]
    assert main([*args, "--method", "preshape"]) == 2
    assert "close_torque is empty" in (err := capsys.readouterr().err)
    assert "--method optimize" in err  # the fix
    assert main(args) == 0  # the optimiser by default, and the output says so
    assert "grasps by optimisation (--method optimize)" in capsys.readouterr().out
    (grasp,) = load_grasps(tmp_path / "out" / "077_rubiks_cube.json")
    assert "thumb" in grasp.extra["fingers"]
    # The file says how to make it again: a user's hand by its folder, not its name.
    generator = json.loads((tmp_path / "out" / "077_rubiks_cube.json").read_text())["generator"]
    assert f"--hand {folder} --object 077_rubiks_cube" in generator["command"]


@pytest.mark.parametrize(
    ("mimic", "envelop", "links"),
    [
        (True, "coupled", ["f1_1", "f1_2", "f2_1", "f2_2", "t_1", "palm"]),
        (True, "none", ["f1_2", "f2_2", "t_1", "palm"]),
        (False, "coupled", ["f1_2", "f2_2", "t_1", "palm"]),
        (False, "all", ["f1_1", "f1_2", "f2_1", "f2_2", "t_1", "palm"]),
    ],
)
def test_a_finger_that_envelops_gets_a_contact_point_on_each_phalanx(
    tmp_path, ball, mimic, envelop, links
):
    """The toy hand's two-link fingers, coupled (``mimic``: one motor per finger) or not, and its
    one-link thumb: each contact point's candidates lie on one link, on its pads (the samples
    whose outward normal leads their motion as the finger closes)."""
    from toy_hand import write_toy_hand

    from wholehand.models.hand import load_hand

    hand = load_hand(write_toy_hand(tmp_path / "toy", mimic=mimic))
    syn = GraspSynthesizer(
        hand, ball, hand.config.grasp_styles["power"], params=SynthesisParams(envelop=envelop)
    )
    on = [{hand.link_names[i] for i in hand.samples.link[c]} for c in syn.candidates]
    assert on == [{link} for link in links]
    assert syn.contact_fingers == [
        {"f1": "index", "f2": "middle", "t_": "thumb", "pa": ""}[link[:2]] for link in links
    ]
    kin = HandKinematics(hand)
    kin.update(syn.q_start, np.eye(4))
    for link, c in zip(links[:-1], syn.candidates[:-1], strict=True):
        s = hand.samples
        p, n = kin.from_joint_frames(s.p_joint[c], s.n_joint[c], s.joint[c])
        tau = np.zeros(hand.nv)
        tau[np.flatnonzero(hand.actuated_dofs)] = 1.0  # every motor closes its finger
        v = np.einsum("nak,k->na", kin.point_jacobians(s.joint[c], p), tau)
        assert (np.einsum("ij,ij->i", n, v) > 0.0).all(), link


def test_generate_tries_each_listed_style_for_what_the_ones_before_left(
    tmp_path, allegro, monkeypatch, capsys
):
    """``--type power,pinch,precision``: the optimiser runs per style in turn, each asked for
    what the styles before it left of --count, each style's grasps in its own file; a style
    after --count is reached is not run. (A fake optimiser: power finds 1 of 3, pinch the 2
    left.)"""
    import wholehand.grasps.optimized as optimized

    calls: list[tuple[str, int]] = []
    found = {"power": 1, "pinch": 5, "precision": 5}

    def fake(hand, obj, count, seed, max_candidates, style, **_):
        calls.append((style, count))
        q = dict.fromkeys(hand.joint_names, 0.0)
        grasps = [Grasp(i, np.eye(4), q, style, 3, {}) for i in range(min(count, found[style]))]
        info = {"command": f"fake --type {style}", "candidates_tried": 4, "rejected": {}}
        return grasps, info

    monkeypatch.setattr(optimized, "synthesize_grasps", fake)
    args = ["grasps", "generate", "--method", "optimize", "--object", "077_rubiks_cube"]
    args += ["--count", "3", "--type", "power,pinch,precision", "--out", str(tmp_path)]
    assert main(args) == 0
    assert calls == [("power", 3), ("pinch", 2)]
    out = capsys.readouterr().out
    assert "1 power grasps" in out and "2 pinch grasps" in out
    assert len(load_grasps(tmp_path / "077_rubiks_cube.json")) == 1
    assert len(load_grasps(tmp_path / "pinch" / "077_rubiks_cube.json")) == 2
    assert not (tmp_path / "precision").exists()
    # An unknown style is named before any work.
    assert main([*args[:-4], "--type", "power,grip", "--out", str(tmp_path / "x")]) == 2
    assert "grip" in capsys.readouterr().err and not (tmp_path / "x").exists()


def test_a_batch_holds_twice_the_starts_the_success_rate_so_far_says_are_needed():
    from wholehand.grasps.optimized import BATCH, MIN_BATCH, batch_size

    assert batch_size(10, found=0, tried=0, room=128) == 20  # a fresh object: all pass
    assert batch_size(4, found=6, tried=11, room=100) == 14  # 7 of 12: 2 * 4 / (7/12)
    assert batch_size(9, found=1, tried=15, room=113) == BATCH  # 1 in 8 pass: full batches
    assert batch_size(1, found=9, tried=10, room=100) == MIN_BATCH
    assert batch_size(10, found=0, tried=0, room=5) == 5  # what is left of the budget
