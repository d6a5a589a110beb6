"""The energy of grasp synthesis and its gradient, over a batch of starts at once.

The terms are those of :mod:`wholehand.grasps.synthesis` (its docstring states them). Every
array carries the batch first: ``B`` starts, ``P`` hand surface samples, ``C`` contact points.
The gradient goes from each point's ``dE/dx`` to the variables through the starts' Jacobian
columns (:meth:`~wholehand.models.batch_kinematics.BatchKinematics.generalized_forces`): one
sum per joint, not one Jacobian per point.

Two forms compute it: the numpy form here, the reference, for any field with the grid's query
methods; and one compiled pass (:mod:`wholehand.grasps.synthesis_kernel`), which the synthesis
uses on an object's SDF grid (:attr:`SynthesisEnergy.compiled`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numba
import numpy as np
import numpy.typing as npt

from wholehand.grasps import synthesis_kernel as kernel
from wholehand.grasps.synthesis_params import SynthesisParams
from wholehand.jit import CACHE
from wholehand.models.batch_kinematics import BatchKinematics, cross
from wholehand.models.hand import HandModel
from wholehand.models.objects import ObjectModel
from wholehand.models.sample_spheres import chunks_along_links, clusters
from wholehand.models.sdf import SignedDistanceGrid

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

SELF_STRIDE = 3
"""Every this-many-th sample of the fingers' links enters the fingers-apart term."""
CHUNK = 8
"""Most samples of the fingers-apart term in one bounding sphere
(:func:`~wholehand.models.sample_spheres.chunks_along_links`)."""
CLUSTER = 8
"""Most hand samples in one bounding sphere of the penetration and table terms' cull
(:func:`~wholehand.models.sample_spheres.clusters`)."""


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


@dataclass(frozen=True)
class Energies:
    """The energies of a batch: each field (B,), as :class:`Energy`'s."""

    total: FloatArray
    distance: FloatArray
    force_closure: FloatArray
    alignment: FloatArray
    penetration: FloatArray
    table: FloatArray
    max_depth: FloatArray
    self_penetration: FloatArray

    def at(self, b: int) -> Energy:
        """Start ``b``'s energy."""
        return Energy(*(float(getattr(self, f.name)[b]) for f in fields(self)))

    def where(self, keep: BoolArray, other: Energies) -> Energies:
        """Per start, this batch's energy where ``keep``, else ``other``'s."""
        return Energies(
            *(np.where(keep, getattr(self, f.name), getattr(other, f.name)) for f in fields(self))
        )


@dataclass(frozen=True)
class _Terms:
    """A batch's energies and what their gradient reuses: at the contacts (B, C, ...) their
    points ``xc`` in the object frame, pad normals ``mc``, SDF values ``dc`` and gradients
    ``gc``, the force-closure sums ``F``, ``T`` (B, 3) and the lever arms ``r``; the
    penetrating samples and those below the table's margin, each as flat indices into the
    (B, P) samples and their (K, 3) points; the fingers-apart samples' points ``Xs``
    (B, S, 3) and their close pairs (start, first, second, distance)."""

    energies: Energies
    xc: FloatArray
    mc: FloatArray
    dc: FloatArray
    gc: FloatArray
    F: FloatArray
    T: FloatArray
    r: FloatArray
    inside: tuple[IntArray, FloatArray]
    below: tuple[IntArray, FloatArray]
    Xs: FloatArray
    self_pairs: tuple[IntArray, IntArray, IntArray, FloatArray]


class SynthesisEnergy:
    """The synthesis energy of one hand about one object (on a table if ``table_up``), for
    batches of states: base poses ``oMb`` (B, 4, 4) in the object frame, optimised joint angles
    ``a`` (B, n_a) [rad] (the actuators' of a coupled hand), contact sample indices (B, C).

    Args:
        hand: The hand.
        obj: The object (its SDF is used).
        q_start: (n_q,) the joint angles that joints outside ``a`` keep [rad].
        table_up: (3,) the table's up direction in the object frame, or None: no table.
        params: Weights.
    """

    def __init__(
        self,
        hand: HandModel,
        obj: ObjectModel,
        q_start: FloatArray,
        table_up: npt.ArrayLike | None,
        params: SynthesisParams,
    ) -> None:
        self.hand, self.obj, self.params = hand, obj, params
        self.samples = hand.samples
        self.sdf = obj.sdf
        self.q_start = q_start
        verts = np.asarray(obj.mesh.vertices, dtype=float)
        self.verts = verts
        self.com = np.asarray(obj.com, dtype=float)
        self.radius = 0.5 * float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0)))
        self.table_up: FloatArray | None = None
        self.table_height = 0.0
        if table_up is not None:
            up = np.asarray(table_up, dtype=float)
            self.table_up = up / np.linalg.norm(up)
            self.table_height = float((verts @ self.table_up).min())
        self.act = hand.actuated_dofs.copy() if hand.coupled else np.ones(hand.nq, dtype=bool)
        self.batch_kin = BatchKinematics(hand)
        self.self_samples, self.self_finger = self._finger_samples()
        self._self_p = self.samples.p_joint[self.self_samples]
        self._self_joint = self.samples.joint[self.self_samples]
        self._cluster_order, self._clusters = clusters(
            self.samples.p_joint, self.samples.joint, self.samples.link, CLUSTER
        )
        self.compiled = True
        """Whether :meth:`energies` takes the compiled pass (on an SDF grid; else always the
        numpy form)."""
        self._kernel_args: tuple[kernel.Scene, kernel.HandPoints] | None = None

    def _finger_samples(self) -> tuple[IntArray, IntArray]:
        """The samples of the fingers-apart term (every :data:`SELF_STRIDE`-th of each
        finger's links past its first), ordered by link and along each link in chunks of at
        most :data:`CHUNK` (:attr:`_chunks`, :attr:`_links`: their bounding spheres), and the
        index of the finger of each."""
        hand, cfg, s = self.hand, self.hand.config, self.samples
        rows, finger = [], []
        for k, links in enumerate(cfg.fingers.values()):
            on = np.flatnonzero(np.isin(s.link, [hand.link_index(n) for n in links[1:]]))
            on = on[::SELF_STRIDE]
            rows.append(on)
            finger.append(np.full(on.size, k))
        if not rows:
            rows, finger = [np.zeros(0, dtype=np.intp)], [np.zeros(0, dtype=np.intp)]
        order = np.concatenate(rows).astype(np.intp)
        fingers = np.concatenate(finger).astype(np.intp)
        order, fingers, self._chunks, self._links = chunks_along_links(
            s.p_joint, s.joint, s.link, order, fingers, CHUNK
        )
        return order, fingers

    def q_of(self, a: FloatArray) -> FloatArray:
        """Joint angles (B, n_q) (or (n_q,) from (n_a,)) from the optimised ones [rad]: the
        start's elsewhere, each coupling's follower from its leader."""
        single = a.ndim == 1
        a = np.atleast_2d(a)
        q = np.repeat(self.q_start[None], a.shape[0], axis=0)
        q[:, self.act] = a
        q = self.hand.couple(q)
        return q[0] if single else q

    # --------------------------------------------------------------------------------------------
    def energies(
        self, oMb: FloatArray, a: FloatArray, contacts: IntArray, gradient: bool = True
    ) -> tuple[Energies, dict[str, FloatArray]]:
        """The energies of a batch and, with ``gradient``, their gradients: ``t`` (B, 3)
        [1/m], ``w`` (B, 3) about each base origin [1/rad], ``a`` (B, n_a) [1/rad]."""
        if self.compiled and isinstance(self.sdf, SignedDistanceGrid):
            energies, grad, _, _ = self._compiled(oMb, a, contacts, gradient)
            return energies, grad
        terms = self._terms(oMb, a, contacts)
        if not gradient:
            return terms.energies, {}
        return terms.energies, self._gradient(contacts, terms)

    def contact_terms(
        self, oMb: FloatArray, a: FloatArray, contacts: IntArray
    ) -> tuple[Energies, FloatArray, FloatArray]:
        """The energies of a batch with the contacts' signed distances (B, C) [m] and unit
        SDF gradients (B, C, 3) (object frame)."""
        if self.compiled and isinstance(self.sdf, SignedDistanceGrid):
            energies, _, dc, gc = self._compiled(oMb, a, contacts, False)
            return energies, dc, gc
        terms = self._terms(oMb, a, contacts)
        return terms.energies, terms.dc, terms.gc

    def _compiled(
        self, oMb: FloatArray, a: FloatArray, contacts: IntArray, gradient: bool
    ) -> tuple[Energies, dict[str, FloatArray], FloatArray, FloatArray]:
        """:meth:`energies` by :func:`~wholehand.grasps.synthesis_kernel.batch_energy`, with
        the contacts' distances and gradients."""
        kin = self.batch_kin
        kin.update(self.q_of(a), oMb)
        scene, points = self._kernel_args or self._kernel_inputs()
        base = np.ascontiguousarray(oMb[:, :3, 3])
        values, force, moment, tau, dc, gc = kernel.batch_energy(
            scene,
            points,
            (kin.R, kin.t, kin.v, kin.w, base, kin.support),
            np.ascontiguousarray(contacts, dtype=np.intp),
            gradient,
        )
        energies = Energies(*(values[:, k] for k in range(len(kernel.ENERGY_COLUMNS))))
        if not gradient:
            return energies, {}, dc, gc
        grad_a = tau @ self.hand.coupling if self.hand.coupled else tau[:, self.act]
        return energies, {"t": force, "w": moment, "a": grad_a}, dc, gc

    def _kernel_inputs(self) -> tuple[kernel.Scene, kernel.HandPoints]:
        """The compiled pass's fixed inputs, made once."""
        s = self.samples
        assert isinstance(self.sdf, SignedDistanceGrid)
        scene = kernel.make_scene(
            self.sdf, (self.com, self.radius), (self.table_up, self.table_height), self.params
        )
        links = self._links
        points = kernel.HandPoints(
            np.ascontiguousarray(s.p_joint, dtype=np.float64),
            np.ascontiguousarray(s.n_joint, dtype=np.float64),
            np.ascontiguousarray(s.joint, dtype=np.intp),
            self._clusters,
            self._cluster_order,
            np.ascontiguousarray(self._self_p, dtype=np.float64),
            np.ascontiguousarray(self._self_joint, dtype=np.intp),
            self._chunks,
            links,
            self.self_finger[self._chunks.bounds[links.bounds[:-1]]].astype(np.intp),
        )
        self._kernel_args = (scene, points)
        return scene, points

    def _terms(self, oMb: FloatArray, a: FloatArray, contacts: IntArray) -> _Terms:
        p, kin, s, sdf = self.params, self.batch_kin, self.samples, self.sdf
        kin.update(self.q_of(a), oMb)
        n, m = oMb.shape[0], s.joint.size
        X, flat = self._near_samples()
        # The depths: the exact lookup only where the nearest node allows a negative distance.
        maybe = sdf.nearest_below(X, sdf.spacing)
        d = sdf.query(X[maybe])
        below_surface = maybe[d < 0.0]
        inside, inside_x, depth = flat[below_surface], X[below_surface], -d[d < 0.0]
        start_of = inside // m
        e_pen = np.bincount(start_of, weights=depth, minlength=n).astype(np.float64)
        max_depth = np.zeros(n)
        np.maximum.at(max_depth, start_of, depth)
        xc = kin.transform_each(s.p_joint, s.joint, contacts)  # (B, C, 3)
        mc = kin.rotate(s.n_joint[contacts], s.joint[contacts])
        dc, gc = sdf.query_with_gradient(xc.reshape(-1, 3))
        dc, gc = dc.reshape(contacts.shape), gc.reshape(xc.shape)
        F = gc.sum(axis=1)
        r = xc - self.com
        T = cross(r, gc).sum(axis=1) / self.radius
        e_dis = np.abs(dc).sum(axis=1)
        e_fc = np.einsum("bi,bi->b", F, F) + np.einsum("bi,bi->b", T, T)
        e_align = (1.0 + np.einsum("bci,bci->bc", mc, gc)).sum(axis=1)
        below, below_x = np.zeros(0, dtype=np.intp), np.zeros((0, 3))
        e_table = np.zeros(n)
        if self.table_up is not None:
            short = p.table_margin - (X @ self.table_up - self.table_height)
            low = short > 0.0
            below, below_x = flat[low], X[low]
            e_table = np.bincount(below // m, weights=short[low], minlength=n).astype(np.float64)
        Xs = kin.transform(self._self_p, self._self_joint)
        pairs = self._self_pairs(Xs)
        overlap = np.maximum(p.self_gap - pairs[3], 0.0)
        e_self = np.bincount(pairs[0], weights=overlap, minlength=n).astype(np.float64)
        total = (
            p.w_dis * e_dis
            + p.w_fc * e_fc
            + p.w_align * e_align
            + p.w_pen * e_pen
            + p.w_table * e_table
            + p.w_self * e_self
        )
        energies = Energies(total, e_dis, e_fc, e_align, e_pen, e_table, max_depth, e_self)
        return _Terms(
            energies, xc, mc, dc, gc, F, T, r, (inside, inside_x), (below, below_x), Xs, pairs
        )

    def _near_samples(self) -> tuple[FloatArray, IntArray]:
        """The hand samples that may lie inside the object or below the table's margin in the
        batch :attr:`batch_kin` holds: their (K, 3) points in the object frame and their flat
        indices ``b * P + i`` into the (B, P) samples. Only the samples of clusters whose
        bounding spheres may reach that far (:meth:`SignedDistanceGrid.near_spheres`, the
        table's plane) are placed: no sample of the others is."""
        kin, clusters, sdf = self.batch_kin, self._clusters, self.sdf
        centres = kin.transform(clusters.centre, clusters.joint).reshape(-1, 3)
        radius = np.tile(clusters.radius, self.batch_kin.size)
        near = sdf.near_spheres(centres, radius, sdf.spacing)
        if self.table_up is not None:
            height = centres @ self.table_up - self.table_height - radius
            near |= height < self.params.table_margin
        return kin.transform_groups(
            self.samples.p_joint,
            self.samples.joint,
            (clusters.bounds, self._cluster_order),
            near.reshape(kin.size, -1),
        )

    def _self_pairs(self, Xs: FloatArray) -> tuple[IntArray, IntArray, IntArray, FloatArray]:
        """Pairs of :attr:`self_samples` on different fingers at most the gap apart at their
        positions ``Xs`` (B, S, 3): their start, the two samples (as indices into
        :attr:`self_samples`) and their distance [m]. Only chunks of links whose bounding
        spheres come that close are searched, sample by sample."""
        rows = np.arange(self.self_samples.size)
        if rows.size < 2 or self.params.w_self == 0.0:
            empty = np.zeros(0, dtype=np.intp)
            return empty, empty, empty, np.zeros(0)
        chunks, links = self._chunks, self._links
        kin = self.batch_kin
        chunk_centres = kin.transform(chunks.centre, chunks.joint)
        link_centres = kin.transform(links.centre, links.joint)
        finger = self.self_finger[chunks.bounds[links.bounds[:-1]]]
        capacity = 4096
        while True:
            found, start, i, j, dist = _close_pairs(
                Xs,
                rows,
                (links.bounds, link_centres, links.radius, finger),
                (chunks.bounds, chunk_centres, chunks.radius),
                self.params.self_gap,
                capacity,
            )
            if found <= capacity:
                return start[:found], i[:found], j[:found], dist[:found]
            capacity = found

    def _gradient(self, contacts: IntArray, e: _Terms) -> dict[str, FloatArray]:
        """The energies' gradients from their terms: dE/dx per point, then through the starts'
        Jacobian columns to the variables."""
        p, s, L, kin = self.params, self.samples, self.radius, self.batch_kin
        m = s.joint.size
        n = contacts.shape[0]
        H = self._normal_jacobians(e.xc.reshape(-1, 3)).reshape(*e.xc.shape, 3)  # d g / d c
        g_fc = np.einsum("znab,za->znb", H, e.F) + cross(e.gc, e.T[:, None]) / L
        g_fc += np.einsum("znab,zna->znb", H, cross(e.T[:, None], e.r)) / L
        g_align = np.einsum("znab,zna->znb", H, e.mc)
        g_c = p.w_dis * np.sign(e.dc)[..., None] * e.gc + 2.0 * p.w_fc * g_fc
        g_c += p.w_align * g_align
        batch = [np.repeat(np.arange(n), contacts.shape[1])]
        joint = [s.joint[contacts].reshape(-1)]
        points, forces = [e.xc.reshape(-1, 3)], [g_c.reshape(-1, 3)]
        inside, inside_x = e.inside
        if inside.size:
            forces.append(-p.w_pen * self.sdf.query_with_gradient(inside_x)[1])
            batch.append(inside // m)
            joint.append(s.joint[inside % m])
            points.append(inside_x)
        below, below_x = e.below
        if below.size:
            assert self.table_up is not None
            forces.append(np.broadcast_to(-p.w_table * self.table_up, (below.size, 3)))
            batch.append(below // m)
            joint.append(s.joint[below % m])
            points.append(below_x)
        start, si, sj, dist = e.self_pairs
        if start.size:  # d(gap - |x - y|)/dx = -(x - y)/|x - y|, and the opposite for y
            xi, xj = e.Xs[start, si], e.Xs[start, sj]
            u = (xi - xj) / np.maximum(dist, 1e-12)[:, None]
            forces += [-p.w_self * u, p.w_self * u]
            batch += [start, start]
            rows = self.self_samples
            joint += [s.joint[rows[si]], s.joint[rows[sj]]]
            points += [xi, xj]
        # The pads' normals turn with their links: dm = omega x m, a moment m x dE/dm.
        moments = np.zeros((sum(len(f) for f in forces), 3))
        moments[: contacts.size] = cross(e.mc, p.w_align * e.gc).reshape(-1, 3)
        force, moment, tau = kin.generalized_forces(
            np.concatenate(batch),
            np.concatenate(joint),
            np.concatenate(points),
            np.concatenate(forces),
            moments,
        )
        grad_a = tau @ self.hand.coupling if self.hand.coupled else tau[:, self.act]
        return {"t": force, "w": moment, "a": grad_a}

    def _normal_jacobians(self, x: FloatArray) -> FloatArray:
        """(N, 3, 3) derivatives of the object normal (the SDF's unit gradient) at points ``x``
        (N, 3) by position [1/m], by central differences over half a grid spacing."""
        h = 0.5 * self.sdf.spacing
        offsets = np.concatenate((np.eye(3), -np.eye(3))) * h  # (6, 3)
        probes = (x[:, None, :] + offsets[None]).reshape(-1, 3)
        g = self.sdf.query_with_gradient(probes)[1].reshape(-1, 6, 3)
        return np.transpose((g[:, :3] - g[:, 3:]) / (2.0 * h), (0, 2, 1))  # [n, a, b] = dg_a/dx_b


@numba.njit(cache=CACHE, nogil=True, inline="always")
def _apart(centres: FloatArray, radius: FloatArray, b: int, g: int, h: int, gap: float) -> bool:
    """Whether spheres ``g`` and ``h`` of start ``b`` stay more than ``gap`` apart."""
    dx = centres[b, g, 0] - centres[b, h, 0]
    dy = centres[b, g, 1] - centres[b, h, 1]
    dz = centres[b, g, 2] - centres[b, h, 2]
    reach = radius[g] + radius[h] + gap
    return bool(dx * dx + dy * dy + dz * dz > reach * reach)


@numba.njit(cache=CACHE, nogil=True, inline="always")
def _sample_pairs(
    X: FloatArray,
    b: int,
    rows: IntArray,
    bounds: IntArray,
    k: int,
    m: int,
    gap: float,
    start: IntArray,
    first: IntArray,
    second: IntArray,
    dist: FloatArray,
    found: int,
) -> int:  # pragma: no cover - jit
    """The pairs of samples of chunks ``k`` and ``m`` of start ``b`` at most ``gap`` apart,
    written into ``start``, ``first``, ``second``, ``dist`` from ``found`` on while they have
    room; the count of pairs found so far."""
    for ii in range(bounds[k], bounds[k + 1]):
        i = rows[ii]
        for jj in range(bounds[m], bounds[m + 1]):
            j = rows[jj]
            ex = X[b, i, 0] - X[b, j, 0]
            ey = X[b, i, 1] - X[b, j, 1]
            ez = X[b, i, 2] - X[b, j, 2]
            d2 = ex * ex + ey * ey + ez * ez
            if d2 <= gap * gap:
                if found < start.shape[0]:
                    start[found] = b
                    first[found] = i
                    second[found] = j
                    dist[found] = np.sqrt(d2)
                found += 1
    return found


@numba.njit(cache=CACHE, nogil=True)
def _close_pairs(
    X: FloatArray,
    rows: IntArray,
    links: tuple[IntArray, FloatArray, FloatArray, IntArray],
    chunks: tuple[IntArray, FloatArray, FloatArray],
    gap: float,
    capacity: int,
) -> tuple[int, IntArray, IntArray, IntArray, FloatArray]:  # pragma: no cover - jit
    """Pairs of samples ``rows`` on two links of different fingers at most ``gap`` apart in
    ``X`` (B, P, 3), searched only between links (bounds into the chunks, centres (B, L, 3),
    radii, finger) and then chunks (bounds into ``rows``, centres (B, K, 3), radii) whose
    spheres come that close: how many there are, and the first ``capacity`` of them as
    (start, sample, sample, distance)."""
    link_bounds, link_centres, link_radius, finger = links
    chunk_bounds, chunk_centres, chunk_radius = chunks
    start = np.empty(capacity, dtype=np.intp)
    first = np.empty(capacity, dtype=np.intp)
    second = np.empty(capacity, dtype=np.intp)
    dist = np.empty(capacity)
    found = 0
    n_links = link_radius.shape[0]
    for b in range(X.shape[0]):
        for g in range(n_links):
            for h in range(g + 1, n_links):
                if finger[g] == finger[h] or _apart(link_centres, link_radius, b, g, h, gap):
                    continue
                for k in range(link_bounds[g], link_bounds[g + 1]):
                    for m in range(link_bounds[h], link_bounds[h + 1]):
                        if _apart(chunk_centres, chunk_radius, b, k, m, gap):
                            continue
                        found = _sample_pairs(
                            X, b, rows, chunk_bounds, k, m, gap, start, first, second, dist, found
                        )
    return found, start, first, second, dist
