"""Power grasps generated in MuJoCo (Dexonomy's grasps are not available offline).

For a hand and an object, each seeded candidate:

1. turns the object to a random orientation and places it against the palm side of the palm
   link (a gap of ``GAP`` [m]), at a random offset along the palm;
2. opens the hand to the power pre-shape of ``[grasping] preshape`` in hand.toml; a candidate
   whose pre-shape already penetrates the object is rejected;
3. holds the object in place with a stiff spring-damper wrench and applies the closing torques of
   ``[grasping] close_torque`` (the other joints are held at the pre-shape by a PD law) until
   the thumb and two other fingers touch the object (MuJoCo contacts), then ``CLOSE_EXTRA`` s more;
4. releases the object and lets the grasp settle for ``SETTLE`` s under the same torques; the
   grasp is kept if the thumb and two fingers still touch, the grasp-loss criterion holds and the
   object moved less than ``MAX_SETTLE_MOTION`` [m].

The hand base pose in the object frame and the joint angles after settling are stored.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from wholehand import registry
from wholehand.grasps.store import Grasp
from wholehand.loop.grasp_loss import GraspLossCheck
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel
from wholehand.models.poses import inverse

FloatArray = npt.NDArray[np.float64]

GAP = (0.001, 0.004)
"""Range of the initial gap between the object and the palm face [m]."""
CONTROL_RATE = 200.0
"""Rate of the closing controller in sim time [Hz]."""
CLOSE_TIMEOUT = 1.5
"""Longest closing phase [s]."""
CLOSE_EXTRA = 0.2
"""Closing time after the thumb and two fingers first touch [s]."""
SETTLE = 0.3
"""Settling time after the object is released [s]."""
MAX_SETTLE_MOTION = 0.01
"""Largest object displacement accepted during settling [m]."""
HOLD_FREQUENCY = 20.0
"""Natural frequency of the critically damped spring that holds the object in place during
closing [Hz]; its gains scale with the object's mass and inertia."""
PD_GAINS = (2.0, 0.05)
"""PD gains holding the non-closing joints at the pre-shape: [N*m/rad], [N*m*s/rad]."""


def palm_face_in_base(hand: HandModel) -> tuple[float, FloatArray]:
    """Where an object can rest against the palm, in the hand base frame.

    Returns the largest x of the palm link's surface samples [m] (its palm-side face, for hands
    built like the Allegro, whose fingers flex toward +x) and the (3,) centre of their bounding
    box [m]. The palm is the root link, so the joint configuration does not matter.
    """
    rows = hand.samples.link == hand.link_index(hand.palm_link)
    p_joint, joint = hand.samples.p_joint[rows], hand.samples.joint[rows]
    pts = HandKinematics(hand).transform_points(p_joint, joint, inverse(hand.wMb))
    return float(pts[:, 0].max()), 0.5 * (pts.min(axis=0) + pts.max(axis=0))


class GraspGenerator:
    """Seeded power-grasp generation for one hand and one object in MuJoCo."""

    def __init__(self, hand: HandModel, obj: ObjectModel, backend: str = "mujoco") -> None:
        self.hand, self.obj = hand, obj
        cfg = hand.config
        if not cfg.close_torque:
            from wholehand.errors import ConfigError

            raise ConfigError(
                f"{cfg.path}: [grasping] close_torque is empty; the grasp generator needs the "
                "closing torque of each flexion joint"
            )
        self.q_pre = np.clip(np.zeros(hand.nq), hand.q_lower, hand.q_upper)
        self.tau_close = np.zeros(hand.nv)
        self.closing = np.zeros(hand.nv, dtype=bool)
        for name, value in cfg.preshape.items():
            self.q_pre[hand.model.joints[hand.model.getJointId(name)].idx_q] = value
        for name, value in cfg.close_torque.items():
            i = hand.model.joints[hand.model.getJointId(name)].idx_v
            self.tau_close[i], self.closing[i] = value, True
        self.backend = registry.load("backends", backend, hand=hand, obj=obj, q_init=self.q_pre)
        self.kin = HandKinematics(hand)
        self.loss = GraspLossCheck(hand, obj)
        thumb = cfg.thumb
        self.thumb = thumb
        # Candidate poses are built in the hand base frame, then mounted with hand.wMb.
        self._palm_face, self._palm_centre = palm_face_in_base(hand)

    def candidate_pose(self, rng: np.random.Generator) -> FloatArray:
        """(4, 4) a seeded object pose against the palm."""
        R = Rotation.random(random_state=rng).as_matrix()
        verts = np.asarray(self.obj.mesh.vertices) @ R.T
        wMo = np.eye(4)
        wMo[:3, :3] = R
        x = self._palm_face - verts[:, 0].min() + rng.uniform(*GAP)
        y = (
            self._palm_centre[1]
            - 0.5 * (verts[:, 1].min() + verts[:, 1].max())
            + rng.uniform(-0.01, 0.01)
        )
        z = rng.uniform(-0.04, 0.0) - 0.5 * (verts[:, 2].min() + verts[:, 2].max())
        wMo[:3, 3] = [x, y, z]
        return self.hand.wMb @ wMo

    def _fingers_touching(self) -> set[str]:
        contacts = self.backend.ground_truth_contacts()
        return {self.hand.link_finger[i] for i in contacts.link} - {""}

    def _grasped(self, fingers: set[str]) -> bool:
        return self.thumb in fingers and len(fingers - {self.thumb}) >= 2

    def _hold(self, wMo: FloatArray) -> None:
        """Hold the object at ``wMo`` with a stiff, critically damped spring."""
        omega = 2.0 * np.pi * HOLD_FREQUENCY
        m, i = self.obj.mass, float(np.linalg.eigvalsh(self.obj.inertia).min())
        self.backend.set_object_spring(
            wMo, (m * omega**2, i * omega**2), (2 * m * omega, 2 * i * omega)
        )

    def _run(self, duration: float, until: Callable[[], bool] | None = None) -> bool:
        b, dt = self.backend, 1.0 / CONTROL_RATE
        for i in range(int(round(duration * CONTROL_RATE))):
            s = b.read_state()
            tau = PD_GAINS[0] * (self.q_pre - s.q) - PD_GAINS[1] * s.dq
            tau[self.closing] = self.tau_close[self.closing]
            b.apply_torques(tau)
            b.step(dt)
            if until is not None and i % 5 == 4 and until():
                return True
        return until is None

    def try_candidate(self, index: int, seed: int) -> Grasp | None:
        """One candidate; the grasp, or None when it is rejected."""
        rng = np.random.default_rng([seed, index])
        wMo = self.candidate_pose(rng)
        b = self.backend
        b.reset(self.q_pre, wMo)
        if np.any(b.ground_truth_contacts().distance < -0.001):
            return None  # the pre-shape penetrates the object
        self._hold(wMo)
        if not self._run(CLOSE_TIMEOUT, lambda: self._grasped(self._fingers_touching())):
            return None
        self._run(CLOSE_EXTRA)
        before = b.read_state().wMo
        b.set_object_spring(None)
        self._run(SETTLE)
        state = b.read_state()
        self.kin.update(state.q, state.wMb)
        moved = float(np.linalg.norm(state.wMo[:3, 3] - before[:3, 3]))
        fingers = self._fingers_touching()
        if (
            moved > MAX_SETTLE_MOTION
            or not self._grasped(fingers)
            or not self.loss.held(self.kin, state.wMo)
        ):
            return None
        hand = self.hand
        q = {
            name: float(state.q[hand.model.joints[hand.model.getJointId(name)].idx_q])
            for name in hand.joint_names
        }
        return Grasp(
            id=-1,
            oMb=inverse(state.wMo) @ state.wMb,
            q=q,
            type="power",
            contacts=len(b.ground_truth_contacts()),
            extra={
                "candidate": index,
                "fingers": sorted(fingers),
                "settle_motion_m": round(moved, 6),
            },
        )

    def generate(
        self, count: int = 10, seed: int = 0, max_candidates: int = 400, progress: bool = False
    ) -> list[Grasp]:
        """Up to ``count`` grasps from at most ``max_candidates`` seeded candidates, in order."""
        from tqdm import tqdm

        grasps: list[Grasp] = []
        bar = tqdm(total=count, desc=f"grasps {self.obj.name}", disable=not progress)
        for index in range(max_candidates):
            grasp = self.try_candidate(index, seed)
            if grasp is not None:
                grasps.append(
                    Grasp(len(grasps), grasp.oMb, grasp.q, grasp.type, grasp.contacts, grasp.extra)
                )
                bar.update(1)
                if len(grasps) == count:
                    break
        bar.close()
        return grasps


def generate_grasps(
    hand: HandModel, obj: ObjectModel, count: int = 10, seed: int = 0,
    max_candidates: int = 400, progress: bool = False,
) -> tuple[list[Grasp], dict[str, object]]:  # fmt: skip
    """Grasps and a description of how they were made (for the file's ``generator`` field)."""
    started = time.perf_counter()
    grasps = GraspGenerator(hand, obj).generate(count, seed, max_candidates, progress)
    info = {
        "command": f"wholehand grasps generate --hand {hand.name} --object {obj.name} "
        f"--count {count} --seed {seed}",
        "seed": seed,
        "method": "power pre-shape, closing torques with the object held, settle released "
        "(wholehand/grasps/generate.py)",
        "candidates_tried": (grasps[-1].extra["candidate"] + 1) if grasps else max_candidates,
        "wall_time_s": round(time.perf_counter() - started, 1),
    }
    return grasps, info
