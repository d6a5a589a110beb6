"""``wholehand bench contacts``: contact-estimation latency at seeded grasp-like states."""

from __future__ import annotations

import time

import numpy as np
import numpy.typing as npt
import trimesh

from wholehand import registry
from wholehand.models.grasp_styles import style_arrays
from wholehand.models.hand import HandModel, load_hand
from wholehand.models.kinematics import HandKinematics
from wholehand.models.object_catalogue import load_object
from wholehand.models.objects import ObjectModel
from wholehand.models.palm import palm_frame
from wholehand.models.poses import inverse, pose_from_xyz_rpy
from wholehand.provenance import provenance
from wholehand.timing import percentiles_us, time_calls

FloatArray = npt.NDArray[np.float64]


def grasp_like_states(
    hand: HandModel, obj: ObjectModel, count: int, seed: int
) -> tuple[FloatArray, FloatArray]:
    """Seeded (q, wMo) pairs with the object resting against the palm and the fingers half closed.

    The object is placed in front of the palm face (see :mod:`wholehand.models.palm`, at the
    power pre-shape) at a random gap of 0-5 mm, tilted by up to 15 deg about the palm axes;
    joints are drawn between 30% and 70% of their range. Returns q (count, n_q) and wMo
    (count, 4, 4).
    """
    rng = np.random.default_rng(seed)
    q_pre, tau_close, _ = style_arrays(hand, hand.config.grasp_styles["power"])
    palm = palm_frame(hand, q_pre, tau_close)
    lo, hi = obj.mesh.bounds
    q = hand.q_lower + rng.uniform(0.3, 0.7, (count, hand.nq)) * (hand.q_upper - hand.q_lower)
    wMo = np.empty((count, 4, 4))
    for i in range(count):
        rpy = rng.uniform(-1.0, 1.0, 3) * np.deg2rad(15.0)
        R = pose_from_xyz_rpy([0, 0, 0], rpy)[:3, :3]
        # Lowest x of the rotated object's bounding-box corners touches the palm face plus a gap.
        corners = np.array(np.meshgrid(*zip(lo, hi, strict=True))).reshape(3, -1).T @ R.T
        x = palm.face - corners[:, 0].min() + rng.uniform(0.0, 0.005)
        bMo = np.eye(4)
        bMo[:3, :3] = palm.bRp @ R
        bMo[:3, 3] = palm.bRp @ np.array([x, *palm.centre[1:]])
        wMo[i] = hand.wMb @ bMo
    return q, wMo


def run_contact_benchmark(
    hand: str = "allegro_right",
    obj: str = "077_rubiks_cube",
    estimator: str = "mesh_sdf",
    cycles: int = 2000,
    seed: int = 0,
    d_thresh: float | None = None,
    k: int | None = None,
    reference_cycles: int = 5,
) -> dict[str, object]:
    """Latency of one estimator over ``cycles`` seeded grasp-like states (JSON-able result)."""
    hand_model, obj_model = load_hand(hand), load_object(obj)
    params = {key: v for key, v in {"d_thresh": d_thresh, "k": k}.items() if v is not None}
    est = registry.load("contact_estimators", estimator, hand=hand_model, obj=obj_model, **params)
    n_states = min(cycles, 200)
    qs, poses = grasp_like_states(hand_model, obj_model, n_states, seed)
    kin = HandKinematics(hand_model)
    counts = []

    def estimate_only(i: int) -> None:
        est.estimate(kin, poses[i % n_states])

    def with_kinematics(i: int) -> None:
        kin.update(qs[i % n_states])
        est.estimate(kin, poses[i % n_states])

    for i in range(n_states):
        kin.update(qs[i])
        counts.append(len(est.estimate(kin, poses[i])))
    full = time_calls(with_kinematics, cycles)
    # Estimate alone, at one fixed configuration per block of calls.
    kin.update(qs[0])
    alone = time_calls(estimate_only, cycles)

    # Reference: the exact signed distance of every candidate point (trimesh), a few cycles.
    mesh: trimesh.Trimesh = obj_model.mesh
    ref_ns, errors = [], []
    for i in range(min(reference_cycles, n_states)):
        kin.update(qs[i])
        p_obj = kin.transform_points(
            hand_model.samples.p_joint, hand_model.samples.joint, inverse(poses[i])
        )
        start = time.perf_counter_ns()
        exact = -trimesh.proximity.signed_distance(mesh, p_obj)  # trimesh: positive inside
        ref_ns.append(time.perf_counter_ns() - start)
        band = np.abs(exact) < 0.02
        errors.append(np.abs(obj_model.sdf.query(p_obj[band]) - exact[band]))
    stats = percentiles_us(alone)
    ref = percentiles_us(ref_ns)
    err = np.concatenate(errors) if errors else np.zeros(0)
    return {
        "benchmark": "contacts",
        "hand": hand_model.name,
        "object": obj_model.name,
        "estimator": estimator,
        "params": params,
        "candidate_points": len(hand_model.samples),
        "kept_contacts_mean": round(float(np.mean(counts)), 2),
        "kept_contacts_max": int(np.max(counts)),
        "estimate": stats,
        "estimate_with_forward_kinematics": percentiles_us(full),
        "reference_exact_trimesh": ref,
        "reference_over_estimate_p50": round(ref["p50_us"] / stats["p50_us"], 1),
        "sdf_abs_error_within_2cm_m": {
            "max": float(err.max()) if err.size else None,
            "p99": float(np.percentile(err, 99)) if err.size else None,
        },
        "cycles": cycles,
        "seed": seed,
        "machine": provenance(),
    }
