"""Numba kernels of the ``mesh_sdf`` estimator's per-cycle hot path (paper Sec. III-B).

One fused kernel, :func:`mesh_sdf_contacts`, does all of :class:`MeshSDFEstimator`'s cycle
(``wholehand_plugins.mesh_sdf``) in one pass without temporaries: joint placements in the object
frame, the cluster cull, the trilinear SDF lookup of the surviving samples, the threshold, the
top-K per link, and the SDF gradient and world transform of the kept points. A numpy version of
the same cycle spends almost all of its time in the per-call overhead of about 30 small array
operations (``wholehand bench contacts`` times the kernel; docs/results.md). Its scratch (a few
kB) is allocated per call inside the kernel: cheaper than passing preallocated buffers in (each
array argument adds dispatch cost) and it keeps the kernel re-entrant, so it may run in several
threads at once.

SDF lookups (:mod:`wholehand.models.sdf_lookup`) reproduce :meth:`SignedDistanceGrid.query` and
:meth:`~SignedDistanceGrid.query_with_gradient` to the last bit.

Compilation: every kernel is ``@numba.njit(cache=CACHE, nogil=True, error_model="numpy")``;
``error_model="numpy"`` makes a float division by zero give inf/NaN instead of raising, which
keeps exception paths (and per-point reference counting of the arrays) out of the loops. The
per-point helpers are also ``inline="always"``. The first call in a fresh environment compiles
(about 2 s) and writes the machine code to a cache; later processes load it (tens of ms). Numba
picks the cache folder in this order: ``$NUMBA_CACHE_DIR`` if set; else ``__pycache__`` next to
this file if writable; else the user cache folder (``~/.cache/numba``). Where none is writable (a
read-only install for a user without a home), the kernels compile in every process, with a
warning that names the fix (:mod:`wholehand.jit`). Cache entries are keyed by the source file's
contents, the argument types, the CPU and the numba version, so a stale entry is never used.

The SDF grid is passed as :func:`~wholehand.models.sdf_lookup.grid_arguments` makes it.
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

from wholehand.jit import CACHE
from wholehand.models.sdf_lookup import grid_tuples, sdf_value, sdf_value_and_gradient

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _joint_poses_in_object(
    wMo: FloatArray, wMb: FloatArray, bRj: FloatArray, bp_j: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Every joint frame's placement in the object frame: rotations (J, 3, 3) and positions
    (J, 3) [m], from the object pose ``wMo`` (4, 4), the hand base pose ``wMb`` (4, 4) and the
    joint placements in the base frame ``bRj`` (J, 3, 3), ``bp_j`` (J, 3) [m]
    (:meth:`HandKinematics.joint_poses_in` with ``fMw = inverse(wMo)``)."""
    oRj = np.empty(bRj.shape)
    op_j = np.empty(bp_j.shape)
    oRb = np.empty((3, 3))
    op_b = np.empty(3)
    for a in range(3):  # oMb = inverse(wMo) @ wMb: oRb = wRo^T wRb, op_b = wRo^T (wp_b - wp_o)
        for c in range(3):
            oRb[a, c] = wMo[0, a] * wMb[0, c] + wMo[1, a] * wMb[1, c] + wMo[2, a] * wMb[2, c]
        op_b[a] = (
            wMo[0, a] * (wMb[0, 3] - wMo[0, 3])
            + wMo[1, a] * (wMb[1, 3] - wMo[1, 3])
            + wMo[2, a] * (wMb[2, 3] - wMo[2, 3])
        )
    for j in range(bRj.shape[0]):
        for a in range(3):
            for c in range(3):
                oRj[j, a, c] = (
                    oRb[a, 0] * bRj[j, 0, c] + oRb[a, 1] * bRj[j, 1, c] + oRb[a, 2] * bRj[j, 2, c]
                )
            op_j[j, a] = (
                oRb[a, 0] * bp_j[j, 0] + oRb[a, 1] * bp_j[j, 1] + oRb[a, 2] * bp_j[j, 2] + op_b[a]
            )
    return oRj, op_j


@numba.njit(cache=CACHE, nogil=True, error_model="numpy", inline="always")
def _flush(
    top: FloatArray,
    n_top: int,
    link: int,
    sel: FloatArray,
    sel_link: IntArray,
    sel_row: IntArray,
    n_sel: int,
) -> int:
    """Append the ``n_top`` best points of ``link`` (rows of ``top``: ranking key, x, y, z,
    sample row) to the selection ``sel`` (M, 3), ``sel_link`` (M,), ``sel_row`` (M,) holding
    ``n_sel`` rows; returns the new count."""
    for m in range(n_top):
        sel[n_sel, 0] = top[m, 1]
        sel[n_sel, 1] = top[m, 2]
        sel[n_sel, 2] = top[m, 3]
        sel_link[n_sel] = link
        sel_row[n_sel] = np.intp(top[m, 4])
        n_sel += 1
    return n_sel


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def mesh_sdf_contacts(  # noqa: C901 - one compiled pass over the samples
    wMo: FloatArray,
    wMb: FloatArray,
    bRj: FloatArray,
    bp_j: FloatArray,
    p_joint: FloatArray,
    point_link: IntArray,
    cluster_start: IntArray,
    cluster_centre: FloatArray,
    cluster_reach: FloatArray,
    cluster_joint: IntArray,
    values: npt.NDArray[np.float32],
    dims: npt.NDArray[np.int64],
    geom: FloatArray,
    d_thresh: float,
    k: int,
    kept: BoolArray,
    hysteresis: float,
) -> tuple[FloatArray, FloatArray, IntArray, FloatArray, IntArray]:
    """One cycle of :class:`MeshSDFEstimator`: contacts of the hand samples with the object SDF.

    Samples are stored sorted by cluster, clusters by link, so each cluster is a contiguous row
    range and each link's rows are contiguous; a cluster's samples share its joint. Per cluster:
    its centre is moved to the object frame; if its SDF value is not below its reach the cluster
    is skipped, else each of its samples is moved and looked up, and one with distance below
    ``d_thresh`` is inserted into the current link's top-K buffer, ranked by its distance less
    ``hysteresis`` if the sample was ``kept`` last cycle (kept sorted by that key; ties keep the
    earlier row, as a stable sort). When the link changes, the buffer is appended to the
    selection. The kept points then get the SDF gradient and are moved to the world frame.

    Args:
        wMo: (4, 4) object pose in the world (a checked rigid transform).
        wMb: (4, 4) hand base pose in the world.
        bRj: (J, 3, 3) joint rotations in the base frame.
        bp_j: (J, 3) joint positions in the base frame [m].
        p_joint: (P, 3) sample positions in their cluster's joint frame [m].
        point_link: (P,) link of each sample, non-decreasing.
        cluster_start: (C + 1,) first row of each cluster, then P.
        cluster_centre: (C, 3) cluster centres in their joint's frame [m].
        cluster_reach: (C,) SDF value [m] at the centre below which the cluster is looked at.
        cluster_joint: (C,) parent joint of each cluster (of all its samples), in [0, J).
        values, dims, geom: the SDF grid (module docstring).
        d_thresh: contact threshold on the signed distance [m].
        k: maximum contacts per link (>= 1).
        kept: (P,) the samples selected last cycle.
        hysteresis: how much closer [m] a new sample must be to displace a kept one (0: the
            paper's plain top-K by distance).

    Returns:
        ``(p_world, n_world, link, distance, row)``, new arrays of N rows (at most k per link)
        ordered by link then ranking key: (N, 3) points on the hand [m] and (N, 3) unit outward
        object normals, world frame; (N,) link indices; (N,) signed distances [m]; (N,) the
        rows of the selected samples (for ``kept`` next cycle).
    """
    shape, g = grid_tuples(dims, geom)
    R, t = _joint_poses_in_object(wMo, wMb, bRj, bp_j)
    # Links are sorted, so at most (last - first + 1) of them hold points.
    n_links = point_link[-1] - point_link[0] + 1 if point_link.shape[0] else 0
    top = np.empty((k, 5))  # the current link's best points: key [m], x, y, z [m], row
    sel = np.empty((n_links * k, 3))  # selected object-frame points [m]
    sel_link = np.empty(n_links * k, dtype=np.intp)
    sel_row = np.empty(n_links * k, dtype=np.intp)
    n_sel = 0
    cur_link = -1
    n_top = 0
    for c in range(cluster_centre.shape[0]):
        j = cluster_joint[c]
        cx, cy, cz = cluster_centre[c, 0], cluster_centre[c, 1], cluster_centre[c, 2]
        x = R[j, 0, 0] * cx + R[j, 0, 1] * cy + R[j, 0, 2] * cz + t[j, 0]
        y = R[j, 1, 0] * cx + R[j, 1, 1] * cy + R[j, 1, 2] * cz + t[j, 1]
        z = R[j, 2, 0] * cx + R[j, 2, 1] * cy + R[j, 2, 2] * cz + t[j, 2]
        if not sdf_value(values, shape, g, x, y, z) < cluster_reach[c]:
            continue
        r00, r01, r02, t0 = R[j, 0, 0], R[j, 0, 1], R[j, 0, 2], t[j, 0]
        r10, r11, r12, t1 = R[j, 1, 0], R[j, 1, 1], R[j, 1, 2], t[j, 1]
        r20, r21, r22, t2 = R[j, 2, 0], R[j, 2, 1], R[j, 2, 2], t[j, 2]
        for r in range(cluster_start[c], cluster_start[c + 1]):
            link = point_link[r]
            if link != cur_link:
                n_sel = _flush(top, n_top, cur_link, sel, sel_link, sel_row, n_sel)
                cur_link = link
                n_top = 0
            px, py, pz = p_joint[r, 0], p_joint[r, 1], p_joint[r, 2]
            x = r00 * px + r01 * py + r02 * pz + t0
            y = r10 * px + r11 * py + r12 * pz + t1
            z = r20 * px + r21 * py + r22 * pz + t2
            d = sdf_value(values, shape, g, x, y, z)
            if not d < d_thresh:
                continue
            if kept[r]:
                d -= hysteresis
            if n_top < k:
                pos = n_top
                n_top += 1
            elif d < top[k - 1, 0]:
                pos = k - 1
            else:
                continue
            while pos > 0 and top[pos - 1, 0] > d:  # insertion sort, stable
                for col in range(5):
                    top[pos, col] = top[pos - 1, col]
                pos -= 1
            top[pos, 0] = d
            top[pos, 1] = x
            top[pos, 2] = y
            top[pos, 3] = z
            top[pos, 4] = r
    n_sel = _flush(top, n_top, cur_link, sel, sel_link, sel_row, n_sel)

    p_world = np.empty((n_sel, 3))
    n_world = np.empty((n_sel, 3))
    link_out = np.empty(n_sel, dtype=np.intp)
    row_out = np.empty(n_sel, dtype=np.intp)
    distance = np.empty(n_sel)
    for i in range(n_sel):
        x, y, z = sel[i, 0], sel[i, 1], sel[i, 2]
        d, gx, gy, gz = sdf_value_and_gradient(values, shape, g, x, y, z)
        for a in range(3):
            p_world[i, a] = wMo[a, 0] * x + wMo[a, 1] * y + wMo[a, 2] * z + wMo[a, 3]
            n_world[i, a] = wMo[a, 0] * gx + wMo[a, 1] * gy + wMo[a, 2] * gz
        link_out[i] = sel_link[i]
        row_out[i] = sel_row[i]
        distance[i] = d
    return p_world, n_world, link_out, distance, row_out
