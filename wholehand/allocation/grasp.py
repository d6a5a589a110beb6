"""Contact frames and the grasp matrix (paper Sec. III-C, Eq. (grasp_matrix)).

Sign conventions, stated once for the whole allocation package:

- A contact force ``f`` is the force applied **by the hand on the object** at the contact point.
- ``ContactSet.n_world`` is the object-surface normal pointing **out of** the object. A pushing
  (compressive) contact force therefore points **into** the object, along ``-n_world``.
- The local contact frame of contact i is the rotation ``wRc_i = [e_n, t_1, t_2]`` (columns in
  world axes) with ``e_n = -n_world[i]`` (into the object) and two tangents, right-handed
  (``e_n x t_1 = t_2``). Local forces are ``f_i = [f_n, f_t1, f_t2]``; ``f_n >= 0`` pushes.
  ``f_world_i = wRc_i @ f_i``.
- Wrenches are ``[force N; torque N*m]`` in world axes, torques taken about the object's centre
  of mass ``c``: ``w = sum_i [f_world_i; (p_i - c) x f_world_i] = G f``.

The tangents are built deterministically from the normal with the branchless construction of
Duff et al., "Building an Orthonormal Basis, Revisited", JCGT 6(1), 2017. It is smooth in the
normal except across the plane ``e_n.z = 0``, where the tangent pair flips; every frame field
over the sphere has such a seam (hairy-ball theorem), this one is at least fixed and documented.
"""

from __future__ import annotations

from typing import cast

import numpy as np
import numpy.typing as npt

from wholehand.allocation import kernels

FloatArray = npt.NDArray[np.float64]


def contact_frames(n_world: FloatArray) -> FloatArray:
    """Local contact frames of N contacts.

    Args:
        n_world: (N, 3) unit object-surface normals, pointing out of the object, world axes.

    Returns:
        (N, 3, 3) rotations ``wRc``: column 0 is the local normal axis ``e_n = -n_world``
        (into the object), columns 1 and 2 the tangents ``t_1``, ``t_2``; right-handed,
        so ``f_world = wRc @ [f_n, f_t1, f_t2]``.
    """
    return cast(FloatArray, kernels.contact_frames(np.ascontiguousarray(n_world, dtype=np.float64)))


def skew(v: FloatArray) -> FloatArray:
    """(..., 3, 3) cross-product matrices: ``skew(v) @ u == cross(v, u)`` for (..., 3) ``v``."""
    v = np.asarray(v, dtype=np.float64)
    S = np.zeros((*v.shape[:-1], 3, 3))
    S[..., 0, 1] = -v[..., 2]
    S[..., 0, 2] = v[..., 1]
    S[..., 1, 0] = v[..., 2]
    S[..., 1, 2] = -v[..., 0]
    S[..., 2, 0] = -v[..., 1]
    S[..., 2, 1] = v[..., 0]
    return S


def grasp_matrix_world(p_world: FloatArray, p_com_world: FloatArray) -> FloatArray:
    """Grasp matrix acting on world-axis contact forces.

    Args:
        p_world: (N, 3) contact points, world frame [m].
        p_com_world: (3,) object centre of mass, world frame [m].

    Returns:
        (6, 3N) matrix ``G_w`` with ``G_w @ f_world.ravel() = [sum f; sum (p - c) x f]``
        (force [N] rows then torque [N*m] rows about the COM, world axes).
    """
    p = np.asarray(p_world, dtype=np.float64)
    n = p.shape[0]
    Gw = np.zeros((6, n, 3))
    Gw[0:3] = np.eye(3)[:, None, :]
    Gw[3:6] = skew(p - np.asarray(p_com_world, dtype=np.float64)).transpose(1, 0, 2)
    return Gw.reshape(6, 3 * n)


def wrench_map(r_world: FloatArray, V: FloatArray) -> FloatArray:
    """Wrench about the COM of forces spanned by per-contact world-axis vectors.

    Args:
        r_world: (N, 3) contact points relative to the COM, world axes [m].
        V: (N, 3, k) per contact, k force directions in world axes (e.g. the frame columns, or
            the friction-pyramid edges).

    Returns:
        (6, kN) matrix mapping the stacked coefficients ``[a_0 (k); ...; a_{N-1} (k)]`` of
        ``f_world_i = V_i a_i`` to ``[sum f; sum r x f]`` [N; N*m].
    """
    r = np.ascontiguousarray(r_world, dtype=np.float64)
    return cast(FloatArray, kernels.wrench_map(r, np.ascontiguousarray(V, dtype=np.float64)))


def grasp_matrix(
    p_world: FloatArray, n_world: FloatArray, p_com_world: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Grasp matrix acting on local contact forces, and the contact frames it uses.

    Args:
        p_world: (N, 3) contact points, world frame [m].
        n_world: (N, 3) unit object-outward normals, world axes.
        p_com_world: (3,) object centre of mass, world frame [m].

    Returns:
        ``(G, wRc)``: ``G`` (6, 3N) maps the stacked local forces ``[f_n, f_t1, f_t2]`` of every
        contact (force applied by the hand on the object [N]) to the net wrench on the object
        ``[force N; torque N*m]`` about the COM in world axes; ``wRc`` (N, 3, 3) are the frames of
        :func:`contact_frames`.
    """
    wRc = contact_frames(n_world)
    r = np.asarray(p_world, dtype=np.float64) - np.asarray(p_com_world, dtype=np.float64)
    return wrench_map(r, wRc), wRc


def local_to_world(wRc: FloatArray, f_local: FloatArray) -> FloatArray:
    """(N, 3) world-axis forces from (N, 3) local forces and (N, 3, 3) frames ``wRc``."""
    return cast(FloatArray, np.einsum("nij,nj->ni", wRc, f_local))
