"""What a hand's model says about how it closes and how it carries its own weight, for
``wholehand hand check`` (:mod:`wholehand.models.check`): each finger joint's role and the
closing direction the model gives it, the palm normal the fingers close toward against
hand.toml's, centres of mass far outside their links, and joints whose motors cannot hold the
links they carry against gravity."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from wholehand.errors import WholehandError
from wholehand.models.hand import HandModel
from wholehand.models.hand_report import HandReport

FloatArray = npt.NDArray[np.float64]

FEW_SAMPLES = 3
"""Links with fewer surface samples than this are reported (``hand check``), and bodies with
fewer are not checked for their centre of mass."""
COM_OUTSIDE = 0.02
"""A moving body's centre of mass farther than this outside the box around its links' surface
samples is reported (an <inertial> origin in the wrong frame or in millimetres) [m]."""


def add_roles(hand: HandModel, report: HandReport) -> None:
    """Each joint's role in its finger (flexion, spread, other) and the closing torque the
    model gives it when hand.toml gives none (:func:`~wholehand.models.grasp_styles.
    derived_close_torque`)."""
    from wholehand.models.grasp_styles import derived_close_torque
    from wholehand.models.motor_roles import motor_roles

    roles = motor_roles(hand)
    derived = derived_close_torque(hand)
    for j in report.joints:
        role = roles.get(j["name"])
        j["finger"] = None if role is None else role.finger
        j["role"] = None if role is None else role.role
        j["derived_close_torque"] = derived.get(j["name"])


PALM_DISAGREES_DEG = 30.0
"""hand.toml's palm_normal farther than this from the model's closing direction is reported."""


def palm_findings(hand: HandModel, report: HandReport) -> None:
    """The palm normal the model gives (the power style's closing motion at its pre-shape) and
    hand.toml's ``palm_normal``, in the summary; a finding where the model gives none, or where
    the two disagree by more than :data:`PALM_DISAGREES_DEG`."""
    from wholehand.models.grasp_styles import style_arrays, with_close_torque
    from wholehand.models.palm import model_palm_normal

    cfg = hand.config
    given = None if cfg.palm_normal is None else np.asarray(cfg.palm_normal, dtype=float)
    q, tau, _ = style_arrays(hand, with_close_torque(hand, cfg.grasp_styles["power"]))
    try:
        model = model_palm_normal(hand, q, tau)
    except WholehandError as err:
        severity = "note" if given is not None else "warning"
        report.add(
            severity,
            f"the model gives no palm normal: {err}",
            "set palm_normal in hand.toml (the palm's normal in the hand's root frame)",
        )
        model = None
    entry: dict[str, Any] = {
        "model": None if model is None else model.round(6).tolist(),
        "hand_toml": None if given is None else (given / np.linalg.norm(given)).tolist(),
    }
    if model is not None and given is not None:
        cos = float(model @ given / np.linalg.norm(given))
        entry["angle_deg"] = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
        if entry["angle_deg"] > PALM_DISAGREES_DEG:
            report.add(
                "warning",
                f"hand.toml's palm_normal is {entry['angle_deg']:.0f} deg from the direction "
                f"the fingers close toward ({entry['model']}, the hand's root frame)",
                "check palm_normal's frame (the URDF root's) and sign",
            )
    report.summary["palm_normal"] = entry


def inertia_findings(hand: HandModel, report: HandReport) -> None:
    """Centres of mass far outside their links' geometry, and joints whose motors cannot hold
    the links they carry against gravity (the worst direction of gravity, at three positions of
    the joints): both point to an <inertial> in the wrong frame or units."""
    model = hand.model
    samples = hand.samples
    for jid in range(1, model.njoints):
        points = samples.p_joint[samples.joint == jid]
        inertia = model.inertias[jid]
        if points.shape[0] < FEW_SAMPLES or inertia.mass <= 0.0:
            continue
        com = np.asarray(inertia.lever)
        outside = float(np.linalg.norm(com - np.clip(com, points.min(0), points.max(0))))
        if outside > COM_OUTSIDE:
            links = [n for n, j in zip(hand.link_names, hand.link_joint, strict=True) if j == jid]
            report.add(
                "warning",
                f"the centre of mass of {links} ({inertia.mass:.3g} kg) lies "
                f"{1e3 * outside:.0f} mm outside their geometry (joint {model.names[jid]!r}'s "
                "frame): gravity and the simulation see a lever the hand does not have",
                "check the <inertial> <origin xyz> of those links in the URDF (the link's "
                "frame, metres)",
            )
    worst = _worst_gravity_torques(hand)
    motors = np.flatnonzero(hand.actuated_dofs & ~hand.arm_dofs)
    over = [v for v in motors if worst[v] > hand.tau_max[v]]
    if over:
        names = {model.joints[j].idx_v: model.names[j] for j in range(1, model.njoints)}
        listed = ", ".join(f"{names[v]} {worst[v]:.3g} > {hand.tau_max[v]:.3g}" for v in over[:4])
        report.add(
            "warning",
            f"gravity on the links needs more torque than the motors' limits at {len(over)} "
            f"joints [N*m]: {listed}{' ...' if len(over) > 4 else ''} (the worst direction of "
            "gravity, joints at a quarter, half and three quarters of their ranges): gravity "
            "compensation saturates and a grasp must hold the fingers up too",
            "check the links' <inertial> mass and origin in the URDF, and the torque limits "
            "([joints] torque_limit in hand.toml)",
        )


def _worst_gravity_torques(hand: HandModel) -> FloatArray:
    """(n_v,) the largest torque [N*m] gravity (9.81 m/s^2) asks of each joint over every
    direction of gravity, at the joints a quarter, half and three quarters through their
    ranges: gravity's torque is linear in its direction, so the worst over unit directions is
    the norm of the torques of the three axes; a coupled hand's actuators carry their
    followers' too (``C^T g``), reported at each actuator's joint."""
    import pinocchio as pin

    model = pin.Model(hand.model)
    data = model.createData()
    finite = np.isfinite(hand.q_lower) & np.isfinite(hand.q_upper)
    lower = np.where(finite, hand.q_lower, 0.0)
    upper = np.where(finite, hand.q_upper, 0.0)
    actuators = np.flatnonzero(hand.actuated_dofs)
    worst = np.zeros(model.nv)
    for share in (0.25, 0.5, 0.75):
        q = hand.couple(np.where(finite, lower + share * (upper - lower), hand.neutral()))
        per_axis = []
        for axis in np.eye(3):
            model.gravity.linear = 9.81 * axis
            g = np.array(pin.computeGeneralizedGravity(model, data, q))
            if hand.coupled:
                g_act = np.zeros(model.nv)
                g_act[actuators] = hand.coupling.T @ g
                g = g_act
            per_axis.append(g)
        worst = np.maximum(worst, np.linalg.norm(np.array(per_axis), axis=0))
    return worst
