"""The MuJoCo backend's servo: a command's joint-target groups as one PD law in torque
(:mod:`wholehand.backends.command`), and the check that an arm's servo is stable at the step."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from wholehand.backends.command import Command
from wholehand.errors import ConfigError
from wholehand.models.hand import HandModel

FloatArray = npt.NDArray[np.float64]


PDTerms = tuple[
    npt.NDArray[np.intp],
    npt.NDArray[np.intp],
    FloatArray | None,
    FloatArray,
    FloatArray,
    FloatArray,
]
"""Target dofs, their q indices, q targets, dq targets, kp, kd (all groups concatenated)."""


ARM_SERVO_STEP_LIMIT = 1.0
"""Largest ``kd * timestep / armature`` accepted for an arm joint's servo: its damping is applied
once per step, so the joint's velocity changes by that fraction of itself per step from the
damping alone (past 1 it changes sign every step, past 2 it grows)."""


def check_arm_servo(hand: HandModel, timestep: float) -> None:
    """Refuse an assembly whose arm servo's damping would overshoot within one step."""
    cfg = hand.config
    if not cfg.arm_joints:
        return
    kd = cfg.arm_gains[1]
    ratio = kd * timestep / cfg.arm_armature
    if ratio > ARM_SERVO_STEP_LIMIT:
        raise ConfigError(
            f"{cfg.path}: the arm servo's kd = {kd} N*m*s/rad with arm_armature = "
            f"{cfg.arm_armature} kg*m^2 at a {timestep} s step gives kd * dt / armature = "
            f"{ratio:.2f} > {ARM_SERVO_STEP_LIMIT}: the arm would shake. Raise [assembly] "
            f"arm_armature to at least {kd * timestep / ARM_SERVO_STEP_LIMIT:g}, lower "
            "arm_gains.kd, or the timestep"
        )


def pd_terms(command: Command) -> PDTerms:
    """The command's target groups as flat arrays (hand joints have one dof each: nq = nv)."""
    dofs, q_ref, dq_ref, kp, kd = [], [], [], [], []
    for g in command.targets:
        dofs.append(g.dofs)
        q_ref.append(g.q if g.q is not None else np.full(g.dofs.shape, np.nan))
        dq_ref.append(g.dq if g.dq is not None else np.zeros(g.dofs.shape))
        kp.append(g.kp if g.q is not None else np.zeros(g.dofs.shape))
        kd.append(g.kd)
    all_dofs = np.concatenate(dofs)
    qidx = all_dofs
    q_all = np.concatenate(q_ref)
    q_out = None if np.isnan(q_all).all() else np.nan_to_num(q_all)
    return all_dofs, qidx, q_out, np.concatenate(dq_ref), np.concatenate(kp), np.concatenate(kd)


def pd_torque(tau: FloatArray, terms: PDTerms, q: FloatArray, dq: FloatArray) -> FloatArray:
    """``tau`` (n_v,) [N*m] with every target group's PD term at the state ``q``, ``dq``."""
    dofs, qidx, q_ref, dq_ref, kp, kd = terms
    out = tau.copy()
    out[dofs] += kd * (dq_ref - dq[dofs])
    if q_ref is not None:
        out[dofs] += kp * (q_ref - q[qidx])
    return out


def terms_of(terms: PDTerms, keep: npt.NDArray[np.bool_]) -> PDTerms | None:
    """The terms of the dofs where ``keep`` (n_v,) holds; None when there are none."""
    dofs, qidx, q_ref, dq_ref, kp, kd = terms
    sel = keep[dofs]
    if not sel.any():
        return None
    return (
        dofs[sel],
        qidx[sel],
        None if q_ref is None else q_ref[sel],
        dq_ref[sel],
        kp[sel],
        kd[sel],
    )
