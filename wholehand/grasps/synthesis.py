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
fingers' links past their first (every :data:`SELF_STRIDE`-th sample), closer than ``gap``: a
finger pressed into another starts MuJoCo's validation with interpenetrating links.

Joint limits are kept by clipping. Each start takes RMSprop-scaled
gradient steps (Pinocchio point and angular Jacobians, the SDF's gradient) and re-draws each
contact point with a small probability; a step is kept by the Metropolis rule at a temperature
that decays geometrically, as in DexGraspNet's annealing.

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
from wholehand.grasps.synthesis_params import SynthesisParams
from wholehand.models.grasp_styles import style_arrays
from wholehand.models.hand import HandModel
from wholehand.models.hand_config import GraspStyle
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel
from wholehand.models.palm import PalmFrame, palm_frame

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


SELF_STRIDE = 3
"""Every this-many-th sample of the fingers' links enters the fingers-apart term."""
MIN_PAD_SAMPLES = 5
"""A finger with fewer pad samples than this takes its contacts anywhere on its links."""


@dataclass(frozen=True)
class Energy:
    """The energy of one state and its parts."""

    total: float
    distance: float
    """Sum of the contacts' |signed distance| [m]."""
    force_closure: float
    alignment: float
    penetration: float
    """Sum of the hand samples' depths inside the object [m]."""
    table: float
    """Sum of the hand samples' depths below the table margin [m]."""
    max_depth: float
    """Deepest hand sample inside the object [m]."""
    self_penetration: float = 0.0
    """Sum over pairs of two fingers' samples of how much closer than the gap they are [m]."""


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


@dataclass(frozen=True)
class _Terms:
    """The energy of a state and what its gradient reuses: the hand's sample points ``X``
    (P, 3) in the object frame, at the contacts their points ``xc``, pad normals ``mc``, SDF
    values ``dc`` and gradients ``gc`` (C, 3), the force-closure sums ``F`` and ``T`` and the
    lever arms ``r``; the penetrating samples, those below the table's margin, and the
    self-penetrating pairs (first, second, distance)."""

    energy: Energy
    X: FloatArray
    xc: FloatArray
    mc: FloatArray
    dc: FloatArray
    gc: FloatArray
    F: FloatArray
    T: FloatArray
    r: FloatArray
    inside: IntArray
    below: IntArray
    self_pairs: tuple[IntArray, IntArray, FloatArray]


class GraspSynthesizer:
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
        self.hand, self.obj, self.style = hand, obj, style
        self.params = params or SynthesisParams()
        self.kin = HandKinematics(hand)
        self.samples = hand.samples
        self.sdf = obj.sdf
        verts = np.asarray(obj.mesh.vertices, dtype=float)
        self.com = np.asarray(obj.com, dtype=float)
        self.radius = 0.5 * float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0)))
        self.verts = verts
        self.table_up: FloatArray | None = None
        self.table_height = 0.0
        if table_up is not None:
            up = np.asarray(table_up, dtype=float)
            self.table_up = up / np.linalg.norm(up)
            self.table_height = float((verts @ self.table_up).min())
        q_pre, tau_close, _ = style_arrays(hand, style)
        self.q_start = q_pre if style.preshape else hand.neutral()
        self.palm: PalmFrame = palm_frame(hand, self.q_start, tau_close)
        self.act = hand.actuated_dofs.copy() if hand.coupled else np.ones(hand.nq, dtype=bool)
        self.a_lower = hand.q_lower[self.act]
        self.a_upper = hand.q_upper[self.act]
        self.candidates = self._contact_candidates(tau_close)
        self.self_samples, self.self_finger = self._finger_samples()

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

    def _finger_samples(self) -> tuple[IntArray, IntArray]:
        """The samples of the fingers-apart term (every :data:`SELF_STRIDE`-th of each
        finger's links past its first) and the index of the finger of each."""
        hand, cfg, s = self.hand, self.hand.config, self.samples
        rows, finger = [], []
        for k, links in enumerate(cfg.fingers.values()):
            on = np.flatnonzero(np.isin(s.link, [hand.link_index(n) for n in links[1:]]))
            on = on[::SELF_STRIDE]
            rows.append(on)
            finger.append(np.full(on.size, k))
        if not rows:
            return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
        return np.concatenate(rows).astype(np.intp), np.concatenate(finger).astype(np.intp)

    def _self_pairs(self, X: FloatArray) -> tuple[IntArray, IntArray, FloatArray]:
        """Pairs (i, j) of :attr:`self_samples` rows on different fingers closer than the gap
        at the sample positions ``X`` (P, 3), and their distances [m]."""
        from scipy.spatial import cKDTree

        rows = self.self_samples
        if rows.size < 2 or self.params.w_self == 0.0:
            empty = np.zeros(0, dtype=np.intp)
            return empty, empty, np.zeros(0)
        pairs = cKDTree(X[rows]).query_pairs(self.params.self_gap, output_type="ndarray")
        i, j = pairs[:, 0], pairs[:, 1]
        other = self.self_finger[i] != self.self_finger[j]
        i, j = rows[i[other]], rows[j[other]]
        return i, j, np.linalg.norm(X[i] - X[j], axis=1)

    def touching(self, result: SynthesisResult, gap: float) -> set[str]:
        """Fingers whose contact of ``result`` lies within ``gap`` [m] of the surface ("" for
        the palm's)."""
        return {f for f, d in zip(self.contact_fingers, result.gaps, strict=True) if abs(d) <= gap}

    def q_of(self, a: FloatArray) -> FloatArray:
        """(n_q,) joint angles from the optimised ones [rad]."""
        q = self.q_start.copy()
        q[self.act] = a
        return self.hand.couple(q) if self.hand.coupled else q

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
        terms = self._terms(state)
        state.energy = terms.energy
        if gradient:
            state.grad = self._gradient(state, terms)
        return terms.energy

    def _terms(self, state: SynthesisState) -> _Terms:
        """The energy's terms at ``state``, with the points they were evaluated at."""
        p, kin, s = self.params, self.kin, self.samples
        kin.update(self.q_of(state.a), state.oMb)
        X = kin.transform_points(s.p_joint, s.joint)  # (P, 3) object frame
        d = self.sdf.query(X)
        c = state.contacts
        xc = X[c]
        mc = kin.from_joint_frames(s.p_joint[c], s.n_joint[c], s.joint[c])[1]
        dc, gc = self.sdf.query_with_gradient(xc)
        F = gc.sum(axis=0)
        r = xc - self.com
        T = np.cross(r, gc).sum(axis=0) / self.radius
        e_dis = float(np.abs(dc).sum())
        e_fc = float(F @ F + T @ T)
        e_align = float((1.0 + np.einsum("ij,ij->i", mc, gc)).sum())
        depth = np.maximum(-d, 0.0)
        e_pen = float(depth.sum())
        below = np.zeros(0, dtype=np.intp)
        e_table = 0.0
        if self.table_up is not None:
            h = X @ self.table_up - self.table_height
            short = np.maximum(p.table_margin - h, 0.0)
            below = np.flatnonzero(short > 0.0)
            e_table = float(short.sum())
        si, sj, dist = self._self_pairs(X)
        e_self = float(np.maximum(p.self_gap - dist, 0.0).sum())
        total = (
            p.w_dis * e_dis
            + p.w_fc * e_fc
            + p.w_align * e_align
            + p.w_pen * e_pen
            + p.w_table * e_table
            + p.w_self * e_self
        )
        max_depth = float(depth.max()) if depth.size else 0.0
        energy = Energy(total, e_dis, e_fc, e_align, e_pen, e_table, max_depth, e_self)
        inside = np.flatnonzero(depth > 0.0)
        return _Terms(energy, X, xc, mc, dc, gc, F, T, r, inside, below, (si, sj, dist))

    def _gradient(self, state: SynthesisState, e: _Terms) -> dict[str, FloatArray]:
        """The energy's gradient at ``state`` from its terms: dE/dx per point, then through
        the point Jacobians to the variables."""
        p, kin, s, c, L = self.params, self.kin, self.samples, state.contacts, self.radius
        H = self._normal_jacobians(e.xc)  # (C, 3, 3): d g_i / d c_i
        g_fc = 2.0 * (np.einsum("nab,a->nb", H, e.F) + np.cross(e.gc, e.T) / L)
        g_fc += 2.0 / L * np.einsum("nab,na->nb", H, np.cross(e.T, e.r))
        g_align = np.einsum("nab,na->nb", H, e.mc)
        gx = [p.w_dis * np.sign(e.dc)[:, None] * e.gc + p.w_fc * g_fc + p.w_align * g_align]
        points, joints = [e.xc], [s.joint[c]]
        X, inside, below = e.X, e.inside, e.below
        if inside.size:
            gin = self.sdf.query_with_gradient(X[inside])[1]
            gx.append(-p.w_pen * gin)
            points.append(X[inside])
            joints.append(s.joint[inside])
        if below.size:
            assert self.table_up is not None
            gx.append(np.broadcast_to(-p.w_table * self.table_up, (below.size, 3)))
            points.append(X[below])
            joints.append(s.joint[below])
        si, sj, dist = e.self_pairs
        if si.size:  # d(gap - |x - y|)/dx = -(x - y)/|x - y|, and the opposite for y
            u = (X[si] - X[sj]) / np.maximum(dist, 1e-12)[:, None]
            gx += [-p.w_self * u, p.w_self * u]
            points += [X[si], X[sj]]
            joints += [s.joint[si], s.joint[sj]]
        G = np.concatenate(gx)
        P = np.ascontiguousarray(np.concatenate(points))
        J = np.concatenate(joints)
        jac = kin.actuation_jacobians(J, P) if self.hand.coupled else kin.point_jacobians(J, P)
        t = state.oMb[:3, 3]
        grad_t = G.sum(axis=0)
        grad_w = np.cross(P - t, G).sum(axis=0)
        grad_a = np.einsum("nak,na->k", jac, G)
        # The pads' normals: dm = omega x m.
        gm = p.w_align * e.gc
        mxg = np.cross(e.mc, gm)
        grad_w += mxg.sum(axis=0)
        Jw = kin.angular_jacobians(s.joint[c])
        if self.hand.coupled:
            Jw = Jw @ self.hand.coupling
        grad_a += np.einsum("nak,na->k", Jw, mxg)
        if not self.hand.coupled:
            grad_a = grad_a[self.act]
        return {"t": grad_t, "w": grad_w, "a": grad_a}

    def _normal_jacobians(self, x: FloatArray) -> FloatArray:
        """(N, 3, 3) derivatives of the object normal (the SDF's unit gradient) at points ``x``
        (N, 3) by position [1/m], by central differences over half a grid spacing."""
        h = 0.5 * self.sdf.spacing
        offsets = np.concatenate((np.eye(3), -np.eye(3))) * h  # (6, 3)
        probes = (x[:, None, :] + offsets[None]).reshape(-1, 3)
        g = self.sdf.query_with_gradient(probes)[1].reshape(-1, 6, 3)
        return np.transpose((g[:, :3] - g[:, 3:]) / (2.0 * h), (0, 2, 1))  # [n, a, b] = dg_a/dx_b

    # --------------------------------------------------------------------------------------------
    def optimise(self, starts: int, seed: int = 0, progress: bool = False) -> list[SynthesisResult]:
        """Run ``starts`` seeded starts; their end states, lowest energy first."""
        from tqdm import tqdm

        p = self.params
        rng = np.random.default_rng(seed)
        states = [self.start(rng) for _ in range(starts)]
        for st in states:
            self.evaluate(st)
        ms = [{k: np.zeros_like(v) for k, v in st.grad.items()} for st in states]
        bar = tqdm(range(p.iterations), desc=f"synthesis {self.obj.name}", disable=not progress)
        for it in bar:
            scale = p.cooling ** (it // p.cooling_every)
            temperature = p.temperature * scale
            for k, st in enumerate(states):
                proposal = self._step(st, ms[k], scale, rng)
                assert st.energy is not None
                e_old = st.energy.total
                e_new = self.evaluate(proposal).total
                if e_new <= e_old or rng.random() < np.exp((e_old - e_new) / temperature):
                    states[k] = proposal
        bar.close()
        out = []
        for k, st in enumerate(states):
            energy = self.evaluate(st, gradient=False)
            xc = self.kin.transform_points(
                self.samples.p_joint[st.contacts], self.samples.joint[st.contacts]
            )
            gaps, normals = self.sdf.query_with_gradient(xc)
            q = self.q_of(st.a)
            out.append(
                SynthesisResult(st.oMb.copy(), q, st.contacts.copy(), normals, gaps, energy, k)
            )
        out.sort(key=lambda r: r.energy.total)
        return out

    def _step(
        self,
        st: SynthesisState,
        ms: dict[str, FloatArray],
        scale: float,
        rng: np.random.Generator,
    ) -> SynthesisState:
        """A proposal: an RMSprop-scaled gradient step from ``st`` and re-drawn contacts."""
        p = self.params
        steps = {
            "t": p.step_translation * scale,
            "w": p.step_rotation * scale,
            "a": p.step_joint * scale,
        }
        move = {}
        for key, g in st.grad.items():
            ms[key] *= 0.9
            ms[key] += 0.1 * g * g
            move[key] = -steps[key] * g / (np.sqrt(ms[key]) + 1e-12)
        oMb = st.oMb.copy()
        oMb[:3, 3] += move["t"]
        turn = Rotation.from_rotvec(move["w"]).as_matrix()
        oMb[:3, :3] = turn @ oMb[:3, :3]
        # The rotation turns about the base origin, so the translation is unchanged by it.
        a = np.clip(st.a + move["a"], self.a_lower, self.a_upper)
        contacts = st.contacts.copy()
        for i, cands in enumerate(self.candidates):
            if rng.random() < p.switch_probability:
                contacts[i] = rng.choice(cands)
        return SynthesisState(oMb, a, contacts)
