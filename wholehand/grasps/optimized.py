"""Grasps from the optimiser (:mod:`wholehand.grasps.synthesis`), validated in MuJoCo.

Each result whose contacts lie near the surface and whose hand barely enters the object is
validated as the pre-shape generator validates its candidates
(:meth:`~wholehand.grasps.generate.GraspGenerator.close_and_settle`): the object held, the hand
closed, the object released, the grasp settled and checked. The closing torques press every
contact point into the object along its normal (:func:`closing_torques`).
"""

from __future__ import annotations

import math
import time

import numpy as np
import numpy.typing as npt

from wholehand.grasps.checks import GraspCheck, passes
from wholehand.grasps.face_schedule import FaceSchedule
from wholehand.grasps.generate import (
    GENERATOR_TABLE,
    MAX_CANDIDATES,
    TABLE_CLEAR,
    GraspGenerator,
    generate_command,
    named_style,
)
from wholehand.grasps.store import Grasp
from wholehand.grasps.synthesis import GraspSynthesizer, SynthesisResult
from wholehand.grasps.synthesis_params import SynthesisParams
from wholehand.models.grasp_styles import with_close_torque
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics, lowest_point
from wholehand.models.objects import ObjectModel
from wholehand.models.poses import inverse
from wholehand.models.resting import RestingFace, resting_pose

FloatArray = npt.NDArray[np.float64]


BATCH = 32
"""Most starts optimised together (one batch of :meth:`GraspSynthesizer.optimise`) before
their results are validated: a start costs about 0.07 ms an iteration in a batch of 32, a
tenth of what one alone costs, and little less in larger batches."""
MIN_BATCH = 8
"""Fewest starts of a batch (about 0.1 ms a start and iteration)."""
SPARE = 2.0
"""A batch holds this many times the starts that the success rate seen so far says the grasps
still wanted need (:func:`batch_size`)."""
MAX_DEPTH = 0.002
"""Deepest hand sample inside the object a result may have to be validated [m]."""
MAX_CONTACT_GAP = 0.01
"""Largest distance from the surface of the contact points of the fingers a grasp needs (the
thumb and two others, or the style's fingers) for a result to be validated [m]."""
CLOSE_SQUEEZE = 5.0
"""Least sum of normal forces of the validation's squeeze before it is scaled [N]."""
OPEN_ANGLE = 0.4
"""How far the pre-grasp opens the joint the closing torques turn most [rad]."""
DEFAULT_CLOSE_TORQUE = 0.1
"""Largest closing torque of a validation when the style names none [N*m]."""


def closing_torques(
    hand: HandModel,
    kin: HandKinematics,
    result: SynthesisResult,
    wMo: FloatArray,
    com_world: FloatArray,
    peak: float,
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Joint torques (n_v,) [N*m] that squeeze the object at the contact points of ``result``
    with forces that balance it as well as the friction cones allow (the paper's allocation QP
    at those contacts, :data:`CLOSE_SQUEEZE` of squeeze), scaled so that the largest is
    ``peak``, and the joints they move (n_v,) bool; where the QP gives no torque, equal normal
    forces. ``kin`` must be at the grasp (``q``, the base in the world); ``com_world`` (3,) is
    the object's centre of mass [m]."""
    from wholehand import registry
    from wholehand.allocation.base import hand_keywords
    from wholehand.contacts.base import ContactSet

    s = hand.samples
    c = result.contacts
    p = kin.transform_points(s.p_joint[c], s.joint[c])
    outward = result.normals @ wMo[:3, :3].T
    J = kin.actuation_jacobians(s.joint[c], p)
    contacts = ContactSet(
        p_world=p,
        n_world=outward,
        link=s.link[c],
        distance=np.zeros(len(c)),
        link_actuated=hand.link_actuated,
        link_fingertip=hand.link_fingertip,
    )
    keywords = {**hand_keywords(hand), "f_n_min": CLOSE_SQUEEZE}  # the validation's own squeeze
    allocator = registry.load("allocators", "qp", **keywords)
    allocation = allocator.allocate(contacts, J, com_world)
    if allocation.fresh and allocation.tau is not None and np.abs(allocation.tau).max() > 0.0:
        tau = hand.joint_torques(allocation.tau)
    else:
        tau = hand.joint_torques(np.einsum("nak,na->k", J, -outward))
    largest = float(np.abs(tau).max())
    if largest == 0.0:
        return np.zeros(hand.nv), np.zeros(hand.nv, dtype=bool)
    tau = tau * (peak / largest)
    return tau, np.abs(tau) > 0.02 * peak


def open_hand(hand: HandModel, q: dict[str, float], tau_close: FloatArray) -> dict[str, float]:
    """The grasp's hand opened against its closing torques (n_v,) [N*m]: each joint turned
    back by :data:`OPEN_ANGLE` times its share of the largest torque, within its limits
    (followers of a coupling follow); the pre-grasp the reacher opens toward
    (:func:`~wholehand.reaching.pregrasp.plan_pregrasp`)."""
    model = hand.model
    idx = [model.joints[model.getJointId(name)] for name in hand.joint_names]
    angles = np.zeros(hand.nq)
    for name, joint in zip(hand.joint_names, idx, strict=True):
        angles[joint.idx_q] = q[name] - OPEN_ANGLE * tau_close[joint.idx_v] / (
            float(np.abs(tau_close).max()) or 1.0
        )
    angles = hand.couple(np.clip(angles, hand.q_lower, hand.q_upper))
    return {
        name: round(float(angles[joint.idx_q]), 9)
        for name, joint in zip(hand.joint_names, idx, strict=True)
    }


def _validate(
    generator: GraspGenerator,
    synthesizer: GraspSynthesizer,
    result: SynthesisResult,
    face: RestingFace | None,
    kin: HandKinematics,
    peak: float,
    index: int,
) -> Grasp | None:
    """One optimised result checked and, if it passes, closed, released and settled in
    MuJoCo (on ``face`` of the table, if given); the grasp or None (the reason counted in
    ``generator.rejections``)."""
    hand, obj, b = generator.hand, generator.obj, generator.backend
    if result.energy.max_depth > MAX_DEPTH:
        generator.rejections["the optimised hand penetrates the object"] += 1
        return None
    if not generator.grasped(synthesizer.touching(result, MAX_CONTACT_GAP)):
        generator.rejections["the required fingers' contacts are off the surface"] += 1
        return None
    if face is None:
        wMb = hand.wMb
        wMo = wMb @ inverse(result.oMb)
        b.reset(result.q, wMo)
    else:
        wMo = resting_pose(obj, face.up, 0.0, (0.0, 0.0), GENERATOR_TABLE.top)
        wMb = wMo @ result.oMb
        if lowest_point(hand, result.q, wMb, kin) < TABLE_CLEAR:
            generator.rejections["the optimised hand reaches into the table"] += 1
            return None
        b.reset(result.q, wMo, wMb)
        b.set_table_contact(True)
    kin.update(result.q, wMb)
    com = wMo[:3, :3] @ obj.com + wMo[:3, 3]
    tau, closing = closing_torques(hand, kin, result, wMo, com, peak)
    grasp = generator.close_and_settle(wMo, (result.q, tau, closing), face, index)
    if grasp is not None:
        grasp.extra["energy"] = round(result.energy.total, 6)
        grasp.extra["pregrasp_q"] = open_hand(hand, grasp.q, tau)
    return grasp


def batch_size(wanted: int, found: int, tried: int, room: int) -> int:
    """Starts of the next batch: :data:`SPARE` times what ``wanted`` more grasps need at the
    success rate so far (``found`` grasps of ``tried`` candidates, smoothed so that a fresh
    object counts as one grasp from one candidate), between :data:`MIN_BATCH` and
    :data:`BATCH`, and at most ``room`` (what is left of the candidate budget). An object held
    in the air, where most candidates pass, gets one batch of about twice ``count`` starts
    rather than :data:`BATCH`; a hard one gets full batches from the second on."""
    rate = (found + 1) / (tried + 1)
    need = math.ceil(SPARE * max(wanted, 1) / rate)
    return max(1, min(room, BATCH, max(MIN_BATCH, need)))


def synthesize_grasps(
    hand: HandModel,
    obj: ObjectModel,
    count: int = 10,
    seed: int = 0,
    max_candidates: int = MAX_CANDIDATES,
    progress: bool = False,
    style: str = "power",
    on_table: bool = False,
    params: SynthesisParams | None = None,
    check: GraspCheck | None = None,
) -> tuple[list[Grasp], dict[str, object]]:
    """Up to ``count`` grasps: batches of starts (:func:`batch_size`) optimised
    (:class:`GraspSynthesizer`), each result close enough to the surface validated in MuJoCo as
    the generator validates its candidates (:meth:`GraspGenerator.close_and_settle`, closing
    torques from :func:`closing_torques`) and, with ``check``, kept only if it passes that too,
    until ``count`` grasps or ``max_candidates`` starts (or Ctrl-C, which keeps the grasps found
    so far). Returns the grasps and a description for the file's ``generator`` field."""
    from tqdm import tqdm

    started = time.perf_counter()
    chosen = with_close_torque(hand, named_style(hand, style))
    generator = GraspGenerator(hand, obj, style=chosen, on_table=on_table)
    peak = max((abs(v) for v in chosen.close_torque.values()), default=DEFAULT_CLOSE_TORQUE)
    rng = np.random.default_rng(seed)
    grasps: list[Grasp] = []
    tried = 0
    bar = tqdm(total=count, desc=f"grasps {obj.name}", disable=not progress)
    kin = HandKinematics(hand)
    schedule = FaceSchedule(generator.faces, count) if on_table else None
    interrupted = False
    try:
        while len(grasps) < count and tried < max_candidates:
            on = schedule.next() if schedule else 0
            face = generator.faces[on] if schedule else None
            found = len(grasps)
            synthesizer = GraspSynthesizer(
                hand, obj, chosen, table_up=None if face is None else face.up, params=params
            )
            wanted = count - len(grasps)
            if schedule and schedule.found[on] < schedule.share:
                wanted = min(wanted, schedule.share - schedule.found[on])
            n = batch_size(wanted, len(grasps), tried, max_candidates - tried)
            results = synthesizer.optimise(n, seed=int(rng.integers(2**31)))
            for result in results:
                tried += 1
                grasp = _validate(generator, synthesizer, result, face, kin, peak, tried - 1)
                grasp = grasp and passes(grasp, check, generator.rejections)
                if grasp is None:
                    continue
                grasps.append(
                    Grasp(len(grasps), grasp.oMb, grasp.q, grasp.type, grasp.contacts, grasp.extra)
                )
                bar.update(1)
                if len(grasps) == count:
                    break
            if schedule:
                schedule.record(on, n, len(grasps) - found)
    except KeyboardInterrupt:  # Ctrl-C: keep what was found
        interrupted = True
    bar.close()
    info: dict[str, object] = {
        "command": generate_command(
            "optimize", hand, obj, count, seed, max_candidates, style, on_table
        ),
        "seed": seed,
        "method": "optimised contacts, force closure and penetration from random starts, "
        "validated by closing, release and settle in MuJoCo (wholehand/grasps/synthesis.py)",
        "candidates_tried": tried,
        **({"grasps_per_face": schedule.found} if schedule else {}),
        **({"interrupted": True} if interrupted else {}),
        "rejected": dict(generator.rejections.most_common()),
        "wall_time_s": round(time.perf_counter() - started, 1),
    }
    return grasps, info
