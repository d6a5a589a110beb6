"""Pre-grasps: each stored grasp opened and backed off until the hand clears the object.

A stored grasp is a hand configuration ``q`` and a base pose ``oMb`` in the object frame. Its
pre-grasp moves the base away from the object, along the line from the object's bounding-box
centre through the palm, by s, and opens the fingers toward the grasp style's pre-shape,
fully once s reaches ``OPEN_DISTANCE``; s grows in ``RETREAT_STEP`` steps until every surface
sample of the hand is at least ``clearance`` from the object (the object's SDF; outside its
grid the distance to the grid plus the grid's own value, a lower bound's close neighbour).

On a table, a grasp is usable only where neither it nor its pre-grasp puts a hand sample below
the table top (:func:`usable_on_table`); of the usable ones the stage machine takes the one whose
pre-grasp palm is nearest the current palm (:func:`nearest_plan`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from wholehand import defaults
from wholehand.backends.table import Table
from wholehand.grasps.store import Grasp
from wholehand.models.grasp_styles import style_arrays, with_close_torque
from wholehand.models.hand import HandModel
from wholehand.models.hand_config import GraspStyle
from wholehand.models.kinematics import HandKinematics, lowest_point
from wholehand.models.objects import ObjectModel
from wholehand.models.poses import rotation_angle

FloatArray = npt.NDArray[np.float64]

RETREAT_STEP: float = 0.005
"""Step of the base's retreat while searching the pre-grasp [m]."""
MAX_RETREAT: float = 0.25
"""Farthest retreat tried [m]; a grasp that needs more has no pre-grasp."""
OPEN_DISTANCE: float = 0.03
"""Retreat at which the fingers are fully open [m]."""
ROTATION_WEIGHT: float = 0.05
"""Metres per radian when comparing palm poses (:func:`nearest_plan`)."""


@dataclass(frozen=True)
class GraspPlan:
    """A stored grasp and its pre-grasp, both in the object frame."""

    grasp_id: int
    oMb_grasp: FloatArray
    """(4, 4) base pose of the grasp in the object frame."""
    q_grasp: FloatArray
    """(n_q,) joint angles of the grasp [rad]."""
    oMb_pre: FloatArray
    """(4, 4) base pose of the pre-grasp in the object frame."""
    q_pre: FloatArray
    """(n_q,) joint angles of the pre-grasp [rad]."""
    retreat: float
    """How far the pre-grasp's base is backed off from the grasp's [m]."""
    table_up: FloatArray | None = None
    """(3,) for a table-top grasp, the object-frame direction that was up when it was made
    (the face the object rested on); None for a grasp made in the air."""
    style: str = "power"
    """The grasp style the grasp was made with (hand.toml ``[grasping]`` or
    ``[grasping.<style>]``)."""
    fingers: tuple[str, ...] = ()
    """The style's fingers, which must all touch to hand over to regulation; empty: the
    thumb and two other fingers."""
    closing: FloatArray | None = None
    """(n_v,) the style's closing torques of the grasp hand [N*m]: the grasp stage squeezes
    these joints past the grasp; None: the stage's own (the power style's)."""


def _min_distance(kin: HandKinematics, hand: HandModel, obj: ObjectModel) -> float:
    samples = hand.samples
    points = kin.transform_points(samples.p_joint, samples.joint)  # object frame: wMb = oMb
    return float(obj.sdf.query(points).min())


def hand_clearance(hand: HandModel, obj: ObjectModel, q: FloatArray, oMb: FloatArray) -> float:
    """Smallest signed distance [m] from the hand's surface samples at ``q``, base at ``oMb``
    (object frame), to the object (negative: the hand is inside it)."""
    kin = HandKinematics(hand)
    kin.update(q, oMb)
    return _min_distance(kin, hand, obj)


def plan_pregrasp(
    hand: HandModel,
    obj: ObjectModel,
    grasp: Grasp,
    q_open: FloatArray,
    clearance: float = defaults.PREGRASP_CLEARANCE,
    style: GraspStyle | None = None,
) -> GraspPlan | None:
    """The pre-grasp of ``grasp`` (see the module docstring); None if none within
    ``MAX_RETREAT``. A grasp that stores its own open hand (``pregrasp_q``, joint angles by
    name: the optimiser's and imported grasps) opens toward that instead of ``q_open``.
    ``style``: the grasp style of a grasp that is not a power grasp (its fingers and closing
    torques go into the plan)."""
    q_grasp = grasp.q_array(hand)
    own = grasp.extra.get("pregrasp_q")
    if own is not None:
        q_open = Grasp(grasp.id, grasp.oMb, dict(own), source=grasp.source).q_array(hand)
    kin = HandKinematics(hand)
    kin.update(q_grasp, grasp.oMb)
    palm = hand.link_index(hand.palm_link)
    rows = hand.samples.link == palm
    palm_centre = kin.transform_points(hand.samples.p_joint[rows], hand.samples.joint[rows]).mean(
        axis=0
    )
    lo, hi = np.asarray(obj.mesh.bounds)
    away = palm_centre - 0.5 * (lo + hi)
    away /= max(float(np.linalg.norm(away)), 1e-9)
    for s in np.arange(RETREAT_STEP, MAX_RETREAT + 1e-9, RETREAT_STEP):
        oMb = grasp.oMb.copy()
        oMb[:3, 3] += s * away
        q = q_grasp + min(1.0, s / OPEN_DISTANCE) * (q_open - q_grasp)
        kin.update(q, oMb)
        if _min_distance(kin, hand, obj) >= clearance:
            up = grasp.extra.get("table_up")
            face = None if up is None else np.asarray(up, dtype=float)
            if style is None:
                return GraspPlan(grasp.id, grasp.oMb.copy(), q_grasp, oMb, q, float(s), face)
            closing = style_arrays(hand, with_close_torque(hand, style))[1]
            return GraspPlan(
                grasp.id,
                grasp.oMb.copy(),
                q_grasp,
                oMb,
                q,
                float(s),
                face,
                style.name,
                tuple(style.fingers),
                closing,
            )
    return None


def usable_on_table(
    hand: HandModel,
    plan: GraspPlan,
    wMo: FloatArray,
    table: Table,
    margin: float = 0.0,
    kinematics: HandKinematics | None = None,
) -> bool:
    """True if neither the grasp nor its pre-grasp comes within ``margin`` [m] of the table
    top (or below it); updates ``kinematics`` (of ``hand``) if given, else a new one (building
    one takes about 0.3 ms: a caller checking many plans in a control cycle passes its own)."""
    kin = HandKinematics(hand) if kinematics is None else kinematics
    return all(
        lowest_point(hand, q, wMo @ oMb, kin) >= table.top + margin
        for q, oMb in ((plan.q_grasp, plan.oMb_grasp), (plan.q_pre, plan.oMb_pre))
    )


def nearest_plan(plans: list[GraspPlan], wMo: FloatArray, wMb_now: FloatArray) -> GraspPlan:
    """The plan whose pre-grasp base pose is nearest ``wMb_now`` (translation [m] plus
    ``ROTATION_WEIGHT`` times the rotation angle [rad])."""

    def cost(plan: GraspPlan) -> float:
        wMb = wMo @ plan.oMb_pre
        angle = rotation_angle(wMb[:3, :3], wMb_now[:3, :3])
        return float(np.linalg.norm(wMb[:3, 3] - wMb_now[:3, 3])) + ROTATION_WEIGHT * angle

    return min(plans, key=cost)
