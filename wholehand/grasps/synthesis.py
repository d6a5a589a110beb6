"""Grasp synthesis by optimisation: many random starts, one energy, annealed gradient steps.

The energy follows the optimisation-based synthesisers (DexGraspNet, Dexonomy, BODex): a few
contact points chosen on the hand's surface samples are pulled onto the object's surface in an
arrangement that can balance a wrench, while the rest of the hand stays out of the object (and,
on a table, above it). Everything is in the object's frame, the object's centre of mass at
``obj.com``; the variables of one start are the hand base pose ``oMb`` and the joint angles
(the actuators' of a coupled hand). For contact points ``c_i`` with signed distance ``d_i`` and
outward object normal ``g_i`` (the SDF's unit gradient), hand outward normals ``m_i`` and every
hand sample ``x``:

    E = w_dis   sum_i |d_i|                                    contacts on the surface [m]
      + w_fc    (|sum_i g_i|^2 + |sum_i (c_i - com) x g_i / L|^2)   unit normal forces balance
      + w_align sum_i (1 + m_i . g_i)                          pads face the object
      + w_pen   sum_x max(0, -d(x))                            hand samples not inside [m]
      + w_table sum_x max(0, margin - h(x))                    hand samples above the table [m]
      + w_self  sum_(x,y) max(0, gap - |x - y|)                 fingers apart [m]

``L`` is the object's radius (half its bounding-box diagonal), so that the torque term is
unitless like the force term. The last sum runs over pairs of surface samples of two different
fingers' links past their first (every third sample), closer than ``gap``: a finger pressed
into another starts MuJoCo's validation with interpenetrating links.
:mod:`wholehand.grasps.synthesis_energy` computes the energy for a batch of starts at once.

Joint limits are kept by clipping. The starts run together as one batch; each takes
RMSprop-scaled gradient steps (through Pinocchio's joint Jacobians and the SDF's gradient) and
re-draws each contact point with a small probability; a step is kept by the Metropolis rule at
a temperature that decays geometrically, as in DexGraspNet's annealing.

The contact points: one per finger of the style (the style's ``fingers``, or every finger of
``[fingers]`` for a power grasp, and then one on the palm face too unless ``palm_contact`` is
off), drawn from the pads of the finger's links past the first (the samples whose outward
normal leads their motion when the finger closes by the style's closing-torque signs). A finger
that envelops (``envelop``: by default one whose phalanges a coupling drives) gets one on the
pads of each of its links instead, so that the grasp rests on its whole length.

The start: the hand's palm frame (:mod:`wholehand.models.palm`) faces the object from a random
direction, at a gap of 1-3 cm from its support along that direction, turned at random about it;
the joints at the style's pre-shape if it has one, else mid-range, jittered.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from wholehand.errors import ConfigError
from wholehand.grasps.synthesis_energy import Energy, SynthesisEnergy
from wholehand.grasps.synthesis_params import SynthesisParams
from wholehand.models.grasp_styles import style_arrays
from wholehand.models.hand import HandModel
from wholehand.models.hand_config import GraspStyle
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel
from wholehand.models.palm import PalmFrame, palm_frame

__all__ = ["Energy", "GraspSynthesizer", "SynthesisResult", "SynthesisState"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


MIN_PAD_SAMPLES = 5
"""A finger with fewer pad samples than this takes its contacts anywhere on its links."""


@dataclass
class SynthesisState:
    """One start's variables."""

    oMb: FloatArray
    """(4, 4) hand base pose in the object frame."""
    a: FloatArray
    """(n_a,) the optimised joint angles (every joint; the actuators of a coupled hand) [rad]."""
    contacts: IntArray
    """(C,) indices into the hand's surface samples."""
    energy: Energy | None = None
    grad: dict[str, FloatArray] = field(default_factory=dict)


@dataclass(frozen=True)
class SynthesisResult:
    """A synthesised grasp before validation."""

    oMb: FloatArray
    """(4, 4) hand base pose in the object frame."""
    q: FloatArray
    """(n_q,) joint angles [rad]."""
    contacts: IntArray
    """(C,) surface-sample indices of the contact points."""
    normals: FloatArray
    """(C, 3) outward object normals at the contact points, object frame."""
    gaps: FloatArray
    """(C,) signed distances of the contact points to the surface [m]."""
    energy: Energy
    start: int
    """Index of the start it came from."""


class GraspSynthesizer(SynthesisEnergy):
    """Optimises grasps of one object for one hand and grasp style (module docstring).

    Args:
        hand: The hand.
        obj: The object (its SDF is used).
        style: The grasp style: its fingers carry the contacts; its pre-shape, if any, is the
            start's joint angles; its closing torques, if any, orient the palm frame.
        table_up: On a table: (3,) the table's up direction in the object frame (the resting
            face's ``up``); the table top is the plane through the object's lowest point along
            it. None: no table.
        params: Weights and schedule.
    """

    def __init__(
        self,
        hand: HandModel,
        obj: ObjectModel,
        style: GraspStyle,
        table_up: npt.ArrayLike | None = None,
        params: SynthesisParams | None = None,
    ) -> None:
        q_pre, tau_close, _ = style_arrays(hand, style)
        q_start = q_pre if style.preshape else hand.neutral()
        super().__init__(hand, obj, q_start, table_up, params or SynthesisParams())
        self.style = style
        self.kin = HandKinematics(hand)
        self.palm: PalmFrame = palm_frame(hand, self.q_start, tau_close)
        self.a_lower = hand.q_lower[self.act]
        self.a_upper = hand.q_upper[self.act]
        self.candidates = self._contact_candidates(tau_close)

    # --------------------------------------------------------------------------------------------
    def _contact_candidates(self, tau_close: FloatArray) -> list[IntArray]:
        """Per contact, the surface samples it may sit on: the pads of a finger's links past
        its first (its one link, if it has one; the samples whose outward normal leads their
        motion when the finger closes, at the start posture), or every sample of those links
        where none does; of each of its links for a finger that envelops; the palm face
        (normal within 45 deg of the palm normal) for a power grasp."""
        hand, cfg, s = self.hand, self.hand.config, self.samples
        kin = self.kin
        kin.update(self.q_start, np.eye(4))
        p, n = kin.from_joint_frames(s.p_joint, s.n_joint, s.joint)  # base frame
        v = np.einsum("nak,k->na", kin.point_jacobians(s.joint, p), np.sign(tau_close))
        speed = np.linalg.norm(v, axis=1)
        pad = np.einsum("ij,ij->i", n, v) > 0.5 * speed
        fingers = list(self.style.fingers) or list(cfg.fingers)
        self.contact_fingers = []
        """The finger of each contact ("" for the palm's)."""
        out: list[IntArray] = []
        for finger in fingers:
            if self._envelops(finger):
                phalanges = [
                    np.flatnonzero((s.link == hand.link_index(name)) & pad)
                    for name in cfg.fingers[finger]
                ]
                phalanges = [p for p in phalanges if p.size >= MIN_PAD_SAMPLES]
                if len(phalanges) > 1:
                    out += phalanges
                    self.contact_fingers += [finger] * len(phalanges)
                    continue
            names = cfg.fingers[finger][1:] or cfg.fingers[finger]  # a one-link finger: itself
            on_links = np.isin(s.link, [hand.link_index(name) for name in names])
            if not on_links.any():
                raise ConfigError(
                    f"{cfg.path}: finger {finger!r} has no surface samples on {list(names)}; the "
                    "synthesiser needs them for its contacts"
                )
            pads = np.flatnonzero(on_links & pad)
            out.append(pads if pads.size >= MIN_PAD_SAMPLES else np.flatnonzero(on_links))
            self.contact_fingers.append(finger)
        if self.params.palm_contact and not self.style.fingers:  # a power grasp
            palm = hand.link_index(cfg.palm_link)
            on_face = np.flatnonzero((s.link == palm) & (n @ self.palm.bRp[:, 0] > 0.7))
            if on_face.size:
                out.append(on_face)
                self.contact_fingers.append("")
        return out

    def _envelops(self, finger: str) -> bool:
        """Whether ``finger`` gets a contact point per phalanx (:attr:`SynthesisParams.envelop`):
        for ``coupled``, when one of its links turns on a joint that follows another (a
        coupling in the palm before the finger does not count)."""
        mode, hand = self.params.envelop, self.hand
        if mode != "coupled":
            return mode == "all"
        joints = (int(hand.link_joint[hand.link_index(n)]) for n in hand.config.fingers[finger])
        return any(hand.model.names[j] in hand.mimics for j in joints)

    def touching(self, result: SynthesisResult, gap: float) -> set[str]:
        """Fingers whose contact of ``result`` lies within ``gap`` [m] of the surface ("" for
        the palm's)."""
        return {f for f, d in zip(self.contact_fingers, result.gaps, strict=True) if abs(d) <= gap}

    def start(self, rng: np.random.Generator) -> SynthesisState:
        """A seeded start (module docstring)."""
        p = self.params
        u = rng.normal(size=3)
        if self.table_up is not None:  # from above: within 60 deg of the table's up
            while float(u @ self.table_up) < 0.5 * np.linalg.norm(u):
                u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        support = float((self.verts @ u).max() - self.com @ u)
        target = self.com + u * (support + rng.uniform(*p.gap))
        # Palm normal (palm x) toward the object: -u, turned at random about it.
        x_p = self.palm.bRp[:, 0]
        R0 = Rotation.align_vectors([-u], [x_p])[0].as_matrix()
        spin = Rotation.from_rotvec(rng.uniform(0.0, 2.0 * np.pi) * u).as_matrix()
        R = spin @ R0
        palm_point = self.palm.bRp @ np.array(
            [self.palm.face, self.palm.centre[1], 0.5 * (self.palm.centre[2] + self.palm.top)]
        )
        oMb = np.eye(4)
        oMb[:3, :3] = R
        oMb[:3, 3] = target - R @ palm_point
        a = self.q_start[self.act] + rng.normal(scale=p.joint_jitter, size=int(self.act.sum()))
        a = np.clip(a, self.a_lower, self.a_upper)
        contacts = np.array([rng.choice(c) for c in self.candidates], dtype=np.intp)
        return SynthesisState(oMb, a, contacts)

    # --------------------------------------------------------------------------------------------
    def evaluate(self, state: SynthesisState, gradient: bool = True) -> Energy:
        """The energy of ``state`` (stored in it), with its gradient in ``state.grad``
        (``t`` (3,) [1/m], ``w`` (3,) about the base origin [1/rad], ``a`` (n_a,) [1/rad])."""
        energies, grad = self.energies(
            state.oMb[None], state.a[None], state.contacts[None], gradient
        )
        state.energy = energies.at(0)
        state.grad = {key: value[0] for key, value in grad.items()}
        return state.energy

    def optimise(self, starts: int, seed: int = 0, progress: bool = False) -> list[SynthesisResult]:
        """Run ``starts`` seeded starts together; their end states, lowest energy first."""
        from tqdm import tqdm

        p = self.params
        if starts < 1:
            return []
        rng = np.random.default_rng(seed)
        first = [self.start(rng) for _ in range(starts)]
        oMb = np.stack([st.oMb for st in first])
        a = np.stack([st.a for st in first])
        contacts = np.stack([st.contacts for st in first])
        energies, grad = self.energies(oMb, a, contacts)
        ms = {key: np.zeros_like(g) for key, g in grad.items()}
        bar = tqdm(range(p.iterations), desc=f"synthesis {self.obj.name}", disable=not progress)
        for it in bar:
            scale = p.cooling ** (it // p.cooling_every)
            temperature = p.temperature * scale
            proposal = self._step(oMb, a, contacts, grad, ms, scale, rng)
            new, new_grad = self.energies(*proposal)
            with np.errstate(over="ignore"):
                chance = np.exp((energies.total - new.total) / temperature)
            keep = (new.total <= energies.total) | (rng.random(starts) < chance)
            oMb = np.where(keep[:, None, None], proposal[0], oMb)
            a = np.where(keep[:, None], proposal[1], a)
            contacts = np.where(keep[:, None], proposal[2], contacts)
            energies = new.where(keep, energies)
            grad = {key: np.where(keep[:, None], new_grad[key], g) for key, g in grad.items()}
        bar.close()
        return self._results(oMb, a, contacts)

    def _results(self, oMb: FloatArray, a: FloatArray, contacts: IntArray) -> list[SynthesisResult]:
        """The batch's end states as results, lowest energy first."""
        energies, dc, gc = self.contact_terms(oMb, a, contacts)
        q = self.q_of(a)
        out = [
            SynthesisResult(
                oMb[k].copy(), q[k], contacts[k].copy(), gc[k], dc[k], energies.at(k), k
            )
            for k in range(len(oMb))
        ]
        out.sort(key=lambda r: r.energy.total)
        return out

    def _step(
        self,
        oMb: FloatArray,
        a: FloatArray,
        contacts: IntArray,
        grad: dict[str, FloatArray],
        ms: dict[str, FloatArray],
        scale: float,
        rng: np.random.Generator,
    ) -> tuple[FloatArray, FloatArray, IntArray]:
        """A proposal per start: an RMSprop-scaled gradient step and re-drawn contacts."""
        p = self.params
        steps = {
            "t": p.step_translation * scale,
            "w": p.step_rotation * scale,
            "a": p.step_joint * scale,
        }
        move = {}
        for key, g in grad.items():
            ms[key] *= 0.9
            ms[key] += 0.1 * g * g
            move[key] = -steps[key] * g / (np.sqrt(ms[key]) + 1e-12)
        new = oMb.copy()
        new[:, :3, 3] += move["t"]
        # The rotation turns about the base origin, so the translation is unchanged by it.
        new[:, :3, :3] = Rotation.from_rotvec(move["w"]).as_matrix() @ oMb[:, :3, :3]
        a = np.clip(a + move["a"], self.a_lower, self.a_upper)
        contacts = contacts.copy()
        for b, i in zip(
            *np.nonzero(rng.random(contacts.shape) < p.switch_probability), strict=True
        ):
            contacts[b, i] = rng.choice(self.candidates[i])
        return new, a, contacts
