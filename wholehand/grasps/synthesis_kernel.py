"""The synthesis energy and its gradient for a batch of starts in one compiled pass.

:func:`batch_energy` computes what :class:`~wholehand.grasps.synthesis_energy.SynthesisEnergy`'s
numpy form computes (the terms of :mod:`wholehand.grasps.synthesis`), start by start, point by
point, with no temporary arrays: the contacts' SDF values, gradients and normal derivatives, the
culled hand samples' depths and heights above the table, the fingers' close pairs, and each
point's ``dE/dx`` summed per joint and then through the start's Jacobian columns. The numpy form
spends most of an annealing step in the overhead of about a hundred small array operations,
whatever the batch; this pass costs what its points cost. Results equal the numpy form's up to
the order of floating-point sums (tests/test_synthesis_kernel.py).

Frames and units are those of :class:`~wholehand.models.batch_kinematics.BatchKinematics`: all
points in the object frame o [m], Jacobian columns about o's origin, the base moment about each
start's base origin. Compilation and its cache: :mod:`wholehand.jit`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
import numpy.typing as npt

from wholehand.grasps.synthesis_params import SynthesisParams
from wholehand.jit import CACHE
from wholehand.models.sample_spheres import Spheres
from wholehand.models.sdf import SignedDistanceGrid
from wholehand.models.sdf_lookup import (
    ball_may_reach,
    grid_arguments,
    grid_tuples,
    nearest_node_value,
    sdf_value_and_gradient,
)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

ENERGY_COLUMNS = (
    "total",
    "distance",
    "force_closure",
    "alignment",
    "penetration",
    "table",
    "max_depth",
    "self_penetration",
)
"""The columns of :func:`batch_energy`'s energies, :class:`Energies`' fields in order."""


class Scene(NamedTuple):
    """What stays fixed over a synthesis: the object's grid and shape, the table, the weights.

    ``values``, ``dims``, ``geom`` are the grid (:func:`~wholehand.models.sdf_lookup.
    grid_arguments`); ``cull`` whether the samples' cull by sphere may use the grid (its
    threshold, one cell, is below the values on the box's faces); ``com`` (3,) [m] and ``radius``
    [m] scale the torque term; ``up`` (3,) is the table's unit up direction and ``table`` its
    (height, margin) [m] (``has_table`` False: no table); ``weights`` (6,) are ``w_dis``, ``w_fc``,
    ``w_align``, ``w_pen``, ``w_table``, ``w_self``; ``gap`` the fingers' gap [m]."""

    values: npt.NDArray[np.float32]
    dims: npt.NDArray[np.int64]
    geom: FloatArray
    cull: bool
    com: FloatArray
    radius: float
    has_table: bool
    up: FloatArray
    table: tuple[float, float]
    weights: FloatArray
    gap: float


def make_scene(
    sdf: SignedDistanceGrid,
    shape: tuple[FloatArray, float],
    table: tuple[FloatArray | None, float],
    params: SynthesisParams,
) -> Scene:
    """The :class:`Scene` of an object's grid, its ``shape`` (centre of mass (3,) [m], radius
    [m]), a ``table`` (unit up direction (3,) or None, height along it [m]) and the weights."""
    up, height = table
    p = params
    return Scene(
        *grid_arguments(sdf),
        sdf.culls_below(sdf.spacing),
        np.ascontiguousarray(shape[0], dtype=np.float64),
        float(shape[1]),
        up is not None,
        np.ascontiguousarray(np.zeros(3) if up is None else up, dtype=np.float64),
        (float(height), float(p.table_margin)),
        np.array([p.w_dis, p.w_fc, p.w_align, p.w_pen, p.w_table, p.w_self]),
        float(p.self_gap),
    )


class HandPoints(NamedTuple):
    """The hand's samples in their joints' frames: ``p_joint`` (P, 3) [m], outward normals
    ``n_joint`` (P, 3), ``joint`` (P,); the cull's ``clusters`` (their bounds index
    ``cluster_order``); the fingers-apart samples in chunk order, ``self_p`` (S, 3) [m] on joints
    ``self_joint`` (S,), with the spheres of their ``chunks`` and of their ``links`` (bounds
    into the chunks) and each link's ``link_finger``."""

    p_joint: FloatArray
    n_joint: FloatArray
    joint: IntArray
    clusters: Spheres
    cluster_order: IntArray
    self_p: FloatArray
    self_joint: IntArray
    chunks: Spheres
    links: Spheres
    link_finger: IntArray


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _place(
    R: FloatArray, t: FloatArray, b: int, j: int, p: FloatArray
) -> tuple[float, float, float]:  # pragma: no cover - jit
    """``R[b, j] p + t[b, j]``."""
    x = R[b, j, 0, 0] * p[0] + R[b, j, 0, 1] * p[1] + R[b, j, 0, 2] * p[2] + t[b, j, 0]
    y = R[b, j, 1, 0] * p[0] + R[b, j, 1, 1] * p[1] + R[b, j, 1, 2] * p[2] + t[b, j, 1]
    z = R[b, j, 2, 0] * p[0] + R[b, j, 2, 1] * p[1] + R[b, j, 2, 2] * p[2] + t[b, j, 2]
    return x, y, z


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def _placed(
    R: FloatArray, t: FloatArray, b: int, joint: IntArray, p_joint: FloatArray
) -> FloatArray:  # pragma: no cover - jit
    """(N, 3) points ``p_joint`` (N, 3) of joints ``joint`` (N,) placed by start ``b``."""
    out = np.empty((p_joint.shape[0], 3))
    for i in range(p_joint.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = _place(R, t, b, joint[i], p_joint[i])
    return out


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _push(
    sums: FloatArray, j: int, x: tuple[float, float, float], f: tuple[float, float, float]
) -> None:  # pragma: no cover - jit
    """Add a force ``f`` at ``x`` to joint ``j``'s force and moment about o's origin."""
    sums[j, 0] += f[0]
    sums[j, 1] += f[1]
    sums[j, 2] += f[2]
    sums[j, 3] += x[1] * f[2] - x[2] * f[1]
    sums[j, 4] += x[2] * f[0] - x[0] * f[2]
    sums[j, 5] += x[0] * f[1] - x[1] * f[0]


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _apart(
    centres: FloatArray, radius: FloatArray, g: int, h: int, gap: float
) -> bool:  # pragma: no cover - jit
    """Whether spheres ``g`` and ``h`` (placed centres (N, 3)) stay more than ``gap`` apart."""
    dx = centres[g, 0] - centres[h, 0]
    dy = centres[g, 1] - centres[h, 1]
    dz = centres[g, 2] - centres[h, 2]
    reach = radius[g] + radius[h] + gap
    return bool(dx * dx + dy * dy + dz * dz > reach * reach)


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def _contacts(  # noqa: PLR0913 - one start's contact terms
    scene: Scene,
    hand: HandPoints,
    R: FloatArray,
    t: FloatArray,
    b: int,
    contacts: IntArray,
    gradient: bool,
    sums: FloatArray,
    dc: FloatArray,
    gc: FloatArray,
) -> tuple[float, float, float]:  # pragma: no cover - jit
    """Start ``b``'s contact terms (distance, force closure, alignment); with ``gradient``,
    each contact's ``dE/dx`` and its pad normal's moment pushed into ``sums`` (J, 6). The SDF
    values and gradients go to ``dc[b]`` (C,) and ``gc[b]`` (C, 3)."""
    shape, geom = grid_tuples(scene.dims, scene.geom)
    values, com = scene.values, scene.com
    w_dis, w_fc, w_align = scene.weights[0], scene.weights[1], scene.weights[2]
    n_c = contacts.shape[1]
    xc = np.empty((n_c, 3))
    mc = np.empty((n_c, 3))
    F = np.zeros(3)
    T = np.zeros(3)
    e_dis = 0.0
    e_align = 0.0
    for c in range(n_c):
        i = contacts[b, c]
        j = hand.joint[i]
        x = _place(R, t, b, j, hand.p_joint[i])
        n = hand.n_joint[i]
        for a in range(3):
            xc[c, a] = x[a]
            mc[c, a] = R[b, j, a, 0] * n[0] + R[b, j, a, 1] * n[1] + R[b, j, a, 2] * n[2]
        d, gx, gy, gz = sdf_value_and_gradient(values, shape, geom, x[0], x[1], x[2])
        dc[b, c] = d
        gc[b, c, 0], gc[b, c, 1], gc[b, c, 2] = gx, gy, gz
        F[0] += gx
        F[1] += gy
        F[2] += gz
        rx, ry, rz = x[0] - com[0], x[1] - com[1], x[2] - com[2]
        T[0] += ry * gz - rz * gy
        T[1] += rz * gx - rx * gz
        T[2] += rx * gy - ry * gx
        e_dis += abs(d)
        e_align += 1.0 + mc[c, 0] * gx + mc[c, 1] * gy + mc[c, 2] * gz
    T /= scene.radius
    e_fc = F[0] * F[0] + F[1] * F[1] + F[2] * F[2] + T[0] * T[0] + T[1] * T[1] + T[2] * T[2]
    if not gradient:
        return e_dis, e_fc, e_align
    h = 0.5 * geom[1]
    L = scene.radius
    H = np.empty((3, 3))  # H[a, k] = d g_a / d x_k, by central differences over half a cell
    p = np.empty(3)
    m = np.empty(3)
    f = np.empty(3)
    for c in range(n_c):
        for k in range(3):
            p[:] = xc[c]
            m[:] = xc[c]
            p[k] = xc[c, k] + h
            m[k] = xc[c, k] - h
            _, px, py, pz = sdf_value_and_gradient(values, shape, geom, p[0], p[1], p[2])
            _, qx, qy, qz = sdf_value_and_gradient(values, shape, geom, m[0], m[1], m[2])
            H[0, k] = (px - qx) / (2.0 * h)
            H[1, k] = (py - qy) / (2.0 * h)
            H[2, k] = (pz - qz) / (2.0 * h)
        g = gc[b, c]
        r = (xc[c, 0] - com[0], xc[c, 1] - com[1], xc[c, 2] - com[2])
        Tr = (T[1] * r[2] - T[2] * r[1], T[2] * r[0] - T[0] * r[2], T[0] * r[1] - T[1] * r[0])
        gT = (g[1] * T[2] - g[2] * T[1], g[2] * T[0] - g[0] * T[2], g[0] * T[1] - g[1] * T[0])
        d = dc[b, c]
        sign = 1.0 if d > 0.0 else (-1.0 if d < 0.0 else 0.0)
        for k in range(3):
            g_fc = H[0, k] * F[0] + H[1, k] * F[1] + H[2, k] * F[2] + gT[k] / L
            g_fc += (H[0, k] * Tr[0] + H[1, k] * Tr[1] + H[2, k] * Tr[2]) / L
            g_align = H[0, k] * mc[c, 0] + H[1, k] * mc[c, 1] + H[2, k] * mc[c, 2]
            f[k] = w_dis * sign * g[k] + 2.0 * w_fc * g_fc + w_align * g_align
        j = hand.joint[contacts[b, c]]
        _push(sums, j, (xc[c, 0], xc[c, 1], xc[c, 2]), (f[0], f[1], f[2]))
        # The pad's normal turns with its link: dm = omega x m, a moment m x dE/dm.
        wg = (w_align * g[0], w_align * g[1], w_align * g[2])
        sums[j, 3] += mc[c, 1] * wg[2] - mc[c, 2] * wg[1]
        sums[j, 4] += mc[c, 2] * wg[0] - mc[c, 0] * wg[2]
        sums[j, 5] += mc[c, 0] * wg[1] - mc[c, 1] * wg[0]
    return e_dis, e_fc, e_align


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def _near(
    scene: Scene, centre: tuple[float, float, float], radius: float
) -> bool:  # pragma: no cover - jit
    """Whether a ball (placed ``centre``, ``radius`` [m]) of hand samples may hold one within a
    cell of the object's surface or below the table's margin."""
    if not scene.cull:
        return True
    shape, geom = grid_tuples(scene.dims, scene.geom)
    if ball_may_reach(scene.values, shape, geom, centre, radius, geom[1]):
        return True
    if not scene.has_table:
        return False
    up = scene.up
    height, margin = scene.table
    return bool(
        centre[0] * up[0] + centre[1] * up[1] + centre[2] * up[2] - height - radius < margin
    )


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def _samples(
    scene: Scene,
    hand: HandPoints,
    R: FloatArray,
    t: FloatArray,
    b: int,
    gradient: bool,
    sums: FloatArray,
) -> tuple[float, float, float]:  # pragma: no cover - jit
    """Start ``b``'s penetration, deepest sample and table terms over the samples of the
    clusters that may reach the object (within a cell) or the table's margin (:func:`_near`);
    with ``gradient``, each such sample's ``dE/dx`` pushed into ``sums``."""
    shape, geom = grid_tuples(scene.dims, scene.geom)
    values, up = scene.values, scene.up
    height, margin = scene.table
    w_pen, w_table = scene.weights[3], scene.weights[4]
    cl = hand.clusters
    e_pen = 0.0
    max_depth = 0.0
    e_table = 0.0
    for k in range(cl.radius.shape[0]):
        if not _near(scene, _place(R, t, b, cl.joint[k], cl.centre[k]), cl.radius[k]):
            continue
        for kk in range(cl.bounds[k], cl.bounds[k + 1]):
            i = hand.cluster_order[kk]
            j = hand.joint[i]
            x = _place(R, t, b, j, hand.p_joint[i])
            value, outside = nearest_node_value(values, shape, geom, x[0], x[1], x[2])
            if value + outside < geom[1]:  # the exact lookup only where it may be negative
                d, gx, gy, gz = sdf_value_and_gradient(values, shape, geom, x[0], x[1], x[2])
                if d < 0.0:
                    e_pen -= d
                    max_depth = max(max_depth, -d)
                    if gradient:
                        _push(sums, j, x, (-w_pen * gx, -w_pen * gy, -w_pen * gz))
            if not scene.has_table:
                continue
            short = margin - (x[0] * up[0] + x[1] * up[1] + x[2] * up[2] - height)
            if short > 0.0:
                e_table += short
                if gradient:
                    _push(sums, j, x, (-w_table * up[0], -w_table * up[1], -w_table * up[2]))
    return e_pen, max_depth, e_table


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _chunk_pairs(
    X: FloatArray,
    joint: IntArray,
    bounds: IntArray,
    k: int,
    m: int,
    scene: Scene,
    gradient: bool,
    sums: FloatArray,
) -> float:  # pragma: no cover - jit
    """The fingers-apart energy of the pairs of samples (placed ``X`` (S, 3), on joints
    ``joint``) of chunks ``k`` and ``m`` at most the gap apart; with ``gradient``, each pair's
    ``dE/dx`` pushed into ``sums``."""
    gap, w_self = scene.gap, scene.weights[5]
    energy = 0.0
    for i in range(bounds[k], bounds[k + 1]):
        for j in range(bounds[m], bounds[m + 1]):
            e = (X[i, 0] - X[j, 0], X[i, 1] - X[j, 1], X[i, 2] - X[j, 2])
            d2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
            if d2 > gap * gap:
                continue
            dist = math.sqrt(d2)
            energy += max(gap - dist, 0.0)
            if gradient:  # d(gap - |x - y|)/dx = -(x - y)/|x - y|, the opposite for y
                s = w_self / max(dist, 1e-12)
                u = (s * e[0], s * e[1], s * e[2])
                _push(sums, joint[i], (X[i, 0], X[i, 1], X[i, 2]), (-u[0], -u[1], -u[2]))
                _push(sums, joint[j], (X[j, 0], X[j, 1], X[j, 2]), u)
    return energy


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def _fingers_apart(
    scene: Scene,
    hand: HandPoints,
    R: FloatArray,
    t: FloatArray,
    b: int,
    gradient: bool,
    sums: FloatArray,
) -> float:  # pragma: no cover - jit
    """Start ``b``'s fingers-apart term: the pairs of samples on links of two fingers at most
    the gap apart, searched only between links and then chunks whose spheres come that close;
    with ``gradient``, each pair's ``dE/dx`` pushed into ``sums``."""
    chunks, links, joint = hand.chunks, hand.links, hand.self_joint
    gap, w_self = scene.gap, scene.weights[5]
    n_s = joint.shape[0]
    if n_s < 2 or w_self == 0.0:
        return 0.0
    X = _placed(R, t, b, joint, hand.self_p)
    chunk_centres = _placed(R, t, b, chunks.joint, chunks.centre)
    link_centres = _placed(R, t, b, links.joint, links.centre)
    energy = 0.0
    n_links = links.radius.shape[0]
    for g in range(n_links):
        for h in range(g + 1, n_links):
            if hand.link_finger[g] == hand.link_finger[h]:
                continue
            if _apart(link_centres, links.radius, g, h, gap):
                continue
            for k in range(links.bounds[g], links.bounds[g + 1]):
                for m in range(links.bounds[h], links.bounds[h + 1]):
                    if not _apart(chunk_centres, chunks.radius, k, m, gap):
                        energy += _chunk_pairs(X, joint, chunks.bounds, k, m, scene, gradient, sums)
    return energy


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def batch_energy(
    scene: Scene,
    hand: HandPoints,
    kin: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray],
    contacts: IntArray,
    gradient: bool,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """The energies of a batch of ``B`` starts and, with ``gradient``, their gradients.

    Args:
        scene: The object, table and weights.
        hand: The hand's samples and their spheres.
        kin: ``(R, t, v, w, base, support)`` of a
            :class:`~wholehand.models.batch_kinematics.BatchKinematics` after its update:
            joint rotations (B, J, 3, 3) and origins (B, J, 3) [m], Jacobian columns (B, n_v, 3)
            about o's origin, base origins (B, 3) [m], and which velocity dimensions move each
            joint (J, n_v).
        contacts: (B, C) the contact samples.
        gradient: Whether to compute the gradient (else its outputs are zero).

    Returns:
        ``(energies, force, moment, tau, dc, gc)``: (B, 8) energies in the order of
        :data:`ENERGY_COLUMNS`; the gradient as the points' ``dE/dx`` summed, (B, 3) [1/m],
        their moment about each base origin (B, 3) [1/rad] and the generalised forces (B, n_v)
        [1/rad]; the contacts' signed distances (B, C) [m] and unit SDF gradients (B, C, 3).
    """
    R, t, v, w, base, support = kin
    n, n_c = contacts.shape
    n_j, n_v = support.shape
    energies = np.zeros((n, 8))
    force = np.zeros((n, 3))
    moment = np.zeros((n, 3))
    tau = np.zeros((n, n_v))
    dc = np.empty((n, n_c))
    gc = np.empty((n, n_c, 3))
    sums = np.empty((n_j, 6))
    wt = scene.weights
    for b in range(n):
        sums[:] = 0.0
        e_dis, e_fc, e_align = _contacts(scene, hand, R, t, b, contacts, gradient, sums, dc, gc)
        e_pen, max_depth, e_table = _samples(scene, hand, R, t, b, gradient, sums)
        e_self = _fingers_apart(scene, hand, R, t, b, gradient, sums)
        total = wt[0] * e_dis + wt[1] * e_fc + wt[2] * e_align
        total += wt[3] * e_pen + wt[4] * e_table + wt[5] * e_self
        energies[b, 0] = total
        energies[b, 1] = e_dis
        energies[b, 2] = e_fc
        energies[b, 3] = e_align
        energies[b, 4] = e_pen
        energies[b, 5] = e_table
        energies[b, 6] = max_depth
        energies[b, 7] = e_self
        if not gradient:
            continue
        for k in range(n_v):
            acc = 0.0
            for j in range(n_j):
                if support[j, k] != 0.0:
                    acc += (
                        v[b, k, 0] * sums[j, 0] + v[b, k, 1] * sums[j, 1] + v[b, k, 2] * sums[j, 2]
                    )
                    acc += (
                        w[b, k, 0] * sums[j, 3] + w[b, k, 1] * sums[j, 4] + w[b, k, 2] * sums[j, 5]
                    )
            tau[b, k] = acc
        for a in range(3):
            force[b, a] = sums[:, a].sum()
            moment[b, a] = sums[:, 3 + a].sum()
        p = base[b]
        moment[b, 0] -= p[1] * force[b, 2] - p[2] * force[b, 1]
        moment[b, 1] -= p[2] * force[b, 0] - p[0] * force[b, 2]
        moment[b, 2] -= p[0] * force[b, 1] - p[1] * force[b, 0]
    return energies, force, moment, tau, dc, gc
