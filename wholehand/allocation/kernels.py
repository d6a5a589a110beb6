"""Numba kernels of the allocation QP's per-cycle terms (:mod:`wholehand.allocation.problem`).

The structured problem of one cycle is a few small products per contact: its frame, its four
pyramid edges in world axes, their wrenches about the centre of mass and their joint torques.
Posed as numpy calls (one batched matmul per contact for the torques among them) they cost about
50 us of Python overhead at 70 contacts; :func:`structured_terms` builds all of them in one
compiled pass, with the actuated contacts' Jacobian rows and the torque rows. The other kernels
do the same for the rest of the problem's small array work: the check that the inputs are
finite, the consistency rows, the forces of the edge weights and the rank certificate of the
null-space basis. The screening loop's kernels are :mod:`wholehand.allocation.screening_kernels`,
the warm start's :mod:`wholehand.allocation.warm_start`.

Each term rounds as the numpy form it replaced (docs/performance.md, "How the kernels round").

Compilation as for the contact kernels (``wholehand_plugins.mesh_sdf.kernels``): ``cache=CACHE``,
``error_model="numpy"``.
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

from wholehand.jit import CACHE, fma

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _frame(nx: float, ny: float, nz: float, R: FloatArray) -> None:  # pragma: no cover - jit
    """Write the contact frame of outward normal ``(nx, ny, nz)`` into the (3, 3) ``R``
    (:func:`wholehand.allocation.grasp.contact_frames` says which frame)."""
    x, y, z = -nx, -ny, -nz
    sign = 1.0 if z >= 0.0 else -1.0
    a = -1.0 / (sign + z)
    b = x * y * a
    R[0, 0], R[1, 0], R[2, 0] = x, y, z
    R[0, 1] = 1.0 + sign * x * x * a
    R[1, 1] = sign * b
    R[2, 1] = -sign * x
    R[0, 2] = b
    R[1, 2] = sign + y * y * a
    R[2, 2] = -y


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def contact_frames(n_world: FloatArray) -> FloatArray:  # pragma: no cover - jit
    """(N, 3, 3) contact frames of (N, 3) outward normals (see the grasp module)."""
    n = n_world.shape[0]
    R = np.empty((n, 3, 3))
    for i in range(n):
        _frame(n_world[i, 0], n_world[i, 1], n_world[i, 2], R[i])
    return R


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _wrench_columns(
    r: FloatArray, V: FloatArray, M: FloatArray, col: int
) -> None:  # pragma: no cover - jit
    """Write the wrenches ``[v; r x v]`` of the k columns of the (3, k) ``V`` applied at ``r``
    into columns ``col .. col + k`` of the (6, .) ``M``."""
    rx, ry, rz = r[0], r[1], r[2]
    for c in range(V.shape[1]):
        vx, vy, vz = V[0, c], V[1, c], V[2, c]
        M[0, col + c] = vx
        M[1, col + c] = vy
        M[2, col + c] = vz
        M[3, col + c] = ry * vz - rz * vy
        M[4, col + c] = rz * vx - rx * vz
        M[5, col + c] = rx * vy - ry * vx


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def wrench_map(r_world: FloatArray, V: FloatArray) -> FloatArray:  # pragma: no cover - jit
    """(6, kN) wrench map of (N, 3, k) per-contact force directions applied at (N, 3) points
    ``r_world`` (see :func:`wholehand.allocation.grasp.wrench_map`)."""
    n, k = V.shape[0], V.shape[2]
    M = np.empty((6, k * n))
    for i in range(n):
        _wrench_columns(r_world[i], V[i], M, k * i)
    return M


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def structured_terms(  # noqa: C901 - one compiled pass over the contacts
    n_world: FloatArray,
    p_world: FloatArray,
    p_com: FloatArray,
    E: FloatArray,
    J_world: FloatArray,
    actuated: BoolArray,
    dofs: IntArray,
    tau_max: FloatArray,
) -> tuple[
    FloatArray, FloatArray, FloatArray, FloatArray, IntArray, FloatArray, IntArray, IntArray,
    FloatArray,
]:  # fmt: skip
    """The per-contact terms of the structured allocation QP, in one pass.

    Args:
        n_world: (N, 3) outward unit normals, world axes.
        p_world: (N, 3) contact points, world frame [m].
        p_com: (3,) object centre of mass, world frame [m].
        E: (3, 4) friction-pyramid edges in local axes (``friction_edges(mu)``).
        J_world: (N, 3, n_v) point Jacobians, world axes [m/rad or -].
        actuated: (N,) contacts on actuated links.
        dofs: (n_a,) commanded joints, increasing.
        tau_max: (n_a,) their torque limits [N*m] (``inf``: no limit).

    Returns:
        ``wRc`` (N, 3, 3) frames; ``r_world`` (N, 3) points about the COM [m]; ``W`` (N, 3, 4)
        edges in world axes; ``G_lam`` (6, 4N) their wrenches; ``act_idx`` (N_act,) the
        actuated contacts; ``J_act`` (3 N_act, n_a) their Jacobians' rows, commanded joints
        only; ``moved`` (k,) positions in ``dofs`` of the joints some actuated contact's
        Jacobian moves; ``torque_rows`` (n_t,) those of them with a finite limit; ``T_lam``
        (n_t, 4N) the edges' torques on those joints, ``T_lam[t, 4 i + e] = J_i[:,
        dofs[torque_rows[t]]] . W_i[:, e]`` (zero columns for contacts not actuated) [m].
    """
    n = n_world.shape[0]
    n_e = E.shape[1]
    n_a = dofs.size
    wRc = np.empty((n, 3, 3))
    r_world = np.empty((n, 3))
    W = np.empty((n, 3, n_e))
    G_lam = np.empty((6, n_e * n))
    for i in range(n):
        R = wRc[i]
        _frame(n_world[i, 0], n_world[i, 1], n_world[i, 2], R)
        for c in range(3):
            r_world[i, c] = p_world[i, c] - p_com[c]
        for row in range(3):
            for e in range(n_e):
                s = fma(R[row, 0], E[0, e], 0.0)
                s = fma(R[row, 1], E[1, e], s)
                W[i, row, e] = fma(R[row, 2], E[2, e], s)
        _wrench_columns(r_world[i], W[i], G_lam, n_e * i)
    act_idx = np.flatnonzero(actuated)
    J_act = np.empty((3 * act_idx.size, n_a))
    is_moved = np.zeros(n_a, dtype=np.bool_)
    for k in range(act_idx.size):
        i = int(act_idx[k])
        for c in range(3):
            for a in range(n_a):
                v = J_world[i, c, dofs[a]]
                J_act[3 * k + c, a] = v
                if v != 0.0:
                    is_moved[a] = True
    moved = np.flatnonzero(is_moved)
    torque_rows = np.flatnonzero(is_moved & np.isfinite(tau_max))
    T_lam = np.zeros((torque_rows.size, n_e * n))
    for k in range(act_idx.size):
        i = int(act_idx[k])
        for t in range(torque_rows.size):
            d = dofs[torque_rows[t]]
            j0, j1, j2 = J_world[i, 0, d], J_world[i, 1, d], J_world[i, 2, d]
            for e in range(n_e):
                s = fma(j0, W[i, 0, e], 0.0)
                s = fma(j1, W[i, 1, e], s)
                T_lam[t, n_e * i + e] = fma(j2, W[i, 2, e], s)
    return wRc, r_world, W, G_lam, act_idx, J_act, moved, torque_rows, T_lam


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def edge_forces(W: FloatArray, lam: FloatArray, rows: IntArray) -> FloatArray:
    """(len(rows), 3) world-axis forces ``W_i lambda_i`` of the contacts ``rows`` [N], from
    (N, 3, 4) edges and (4N,) edge weights. The four products are summed as numpy's ``einsum``
    sums them (two lanes: ``(p0 + p2) + (p1 + p3)``)."""
    out = np.empty((rows.size, 3))
    for k in range(rows.size):
        i = rows[k]
        l0, l1, l2, l3 = lam[4 * i], lam[4 * i + 1], lam[4 * i + 2], lam[4 * i + 3]
        for c in range(3):
            out[k, c] = (W[i, c, 0] * l0 + W[i, c, 2] * l2) + (W[i, c, 1] * l1 + W[i, c, 3] * l3)
    return out


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _finite(a: FloatArray) -> bool:  # pragma: no cover - jit
    for x in a.ravel():
        if not np.isfinite(x):
            return False
    return True


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def finite_inputs(
    p_world: FloatArray, n_world: FloatArray, J_world: FloatArray, p_com: FloatArray
) -> bool:  # pragma: no cover - jit
    """True when the contact points and normals (N, 3), the Jacobians (N, 3, n_v) and the centre
    of mass (3,) hold no NaN or inf."""
    return _finite(p_world) and _finite(n_world) and _finite(J_world) and _finite(p_com)


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def consistency_rows(Nc: FloatArray, W: FloatArray, act_idx: IntArray) -> FloatArray:
    """(k, 4N) consistency rows on the edge weights: row j, columns of contact ``act_idx[a]``:
    ``Nc[a, :, j] . W[act_idx[a]]`` (the basis columns' components at that contact times its
    edges), zero for contacts not actuated. ``Nc`` (N_act, 3, k): basis columns by contact;
    ``W`` (N, 3, 4): edges in world axes. Summed as ``einsum`` sums it (from zero, in order)."""
    n_e = W.shape[2]
    k = Nc.shape[2]
    out = np.zeros((k, n_e * W.shape[0]))
    for j in range(k):
        for a in range(act_idx.size):
            i = act_idx[a]
            n0, n1, n2 = Nc[a, 0, j], Nc[a, 1, j], Nc[a, 2, j]
            for e in range(n_e):
                out[j, n_e * i + e] = 0.0 + n0 * W[i, 0, e] + n1 * W[i, 1, e] + n2 * W[i, 2, e]
    return out


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def sigma_min_lower_bound(qr: FloatArray, k: int) -> float:  # pragma: no cover - jit
    """A lower bound of the smallest singular value of the upper-triangular ``R``, the upper
    triangle of ``qr[:k, :k]`` (as LAPACK's ``dgeqrf`` leaves it): ``1 / ||R^-1||_F``, from
    ``R^-1`` by back substitution (``sigma_min = 1 / ||R^-1||_2 >= 1 / ||R^-1||_F``). Zero when
    ``R`` is singular or not finite. About 1e-13 relative rounding error for well-conditioned
    ``R``; callers compare it with a margin."""
    X = np.zeros((k, k))
    for j in range(k):
        d = qr[j, j]
        if d == 0.0 or not np.isfinite(d):
            return 0.0
        X[j, j] = 1.0 / d
        for i in range(j - 1, -1, -1):
            s = 0.0
            for m in range(i + 1, j + 1):
                s += qr[i, m] * X[m, j]
            X[i, j] = -s / qr[i, i]
    total = 0.0
    for j in range(k):
        for i in range(j + 1):
            total += X[i, j] * X[i, j]
    if not np.isfinite(total) or total == 0.0:
        return 0.0
    return float(1.0 / np.sqrt(total))


__all__ = [
    "consistency_rows",
    "contact_frames",
    "edge_forces",
    "finite_inputs",
    "sigma_min_lower_bound",
    "structured_terms",
    "wrench_map",
]
