"""What one allocation leaves for the next: its solution and binding rows, by contact identity.

Warm start (:class:`WarmStart`, driven by the allocator). The torque rows binding last cycle (by
joint) and, when the contacts sit on the same links in the same order, the consistency rows
binding last cycle (by basis index) seed the working set, which saves screening rounds. Solvers
that use a primal start (OSQP, qpsolvers) get the previous edge weights, each contact matched to
the previous contact on the same link with the nearest point (within ``match_radius``). DAQP
instead restarts from its own previous working set; with edge screening, each cycle starts from
the edges that carried force last cycle and every edge of a new contact. Measured effect
(``wholehand bench allocate``): large where rows bind (fewer rounds) and for OSQP; none for PIQP
(interior point).

The per-cycle work (matching the contacts, last cycle's edge weights per contact, the rows of
last cycle's binding joints) is compiled, as the problem's terms are
(:mod:`wholehand.allocation.kernels`). :func:`matched_contacts` takes squared distances
directly, where numpy expanded them before: only a distance within rounding of the radius could
match differently, and the match serves edge screening and primal warm starts only, which no
committed study uses.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, cast

import numba
import numpy as np
import numpy.typing as npt

from wholehand.jit import CACHE

if TYPE_CHECKING:
    from wholehand.allocation.problem import AllocationQP
    from wholehand.contacts.base import ContactSet

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

MATCH_RADIUS: float = 0.005
"""Contacts on the same link closer than this across cycles are the same contact [m]."""


@dataclass
class WarmStart:
    """What one cycle leaves for the next: solution and binding rows, keyed by contact identity."""

    match_radius: float = MATCH_RADIUS
    """Same link and closer than this [m]: the same contact."""
    p_world: FloatArray | None = None
    """(N, 3) previous contact points [m]."""
    link: IntArray | None = None
    """(N,) previous contact links."""
    lam: FloatArray | None = None
    """(N, 4) previous edge weights [N]."""
    torque_dofs: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    """Joint indices whose torque rows were binding."""
    null_rows: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    """Consistency-row indices that were binding."""
    sides: tuple[int, IntArray, npt.NDArray[np.int8], npt.NDArray[np.int8]] | None = None
    """The dual active-set solver's active rows and at which bound (+1 lower, -1 upper): the
    minimum squeeze's, the torque rows' by joint index (joints (k,), sides (k,)) and every
    consistency row's by index ((n_null,)); None: none kept."""
    null_scale: FloatArray | None = None
    """(n_null,) the consistency rows' norms the dual active-set solver learnt."""

    def clear(self) -> None:
        """Forget everything."""
        self.p_world = self.link = self.lam = None
        self.torque_dofs = np.zeros(0, dtype=np.intp)
        self.null_rows = np.zeros(0, dtype=np.intp)
        self.sides = None
        self.null_scale = None

    def keep_sides(self, qp: AllocationQP, y: FloatArray, null_scale: FloatArray) -> None:
        """Keep which rows were active in the dual active-set solution of ``qp`` (its rows'
        multipliers ``y``, in the order of
        :func:`~wholehand.allocation.solvers.dual_active_set.allocation_rows`) and the
        consistency rows' norms it learnt."""
        self.null_scale = null_scale
        side = np.sign(y).astype(np.int8)
        n_t = qp.torque_rows.size
        torque = side[1 : 1 + n_t]
        held = np.flatnonzero(torque)
        self.sides = (int(side[0]), qp.dofs[qp.torque_rows[held]], torque[held], side[1 + n_t :])

    def dual_start(
        self, qp: AllocationQP, contacts: ContactSet
    ) -> tuple[BoolArray | None, npt.NDArray[np.int8] | None, FloatArray | None]:
        """The dual active-set solver's start for ``qp``: the edge weights that carried force
        last cycle (matched by contact; a new contact's start at zero), last cycle's active
        rows (the torque rows by joint; the consistency rows while the contacts sit on the
        same links) and, on the same links, the consistency rows' norms; Nones without a
        previous cycle."""
        if self.lam is None:
            return None, None, None
        lam0, _ = warm_edge_weights(self.match(contacts.p_world, contacts.link), self.lam)
        free = (lam0 > 0.0) & np.isfinite(lam0)
        n_t = qp.torque_rows.size
        rows = np.zeros(1 + n_t + qp.n_null, dtype=np.int8)
        same = self.same_links(contacts.link)
        if self.sides is not None:
            squeeze, joints, torque_sides, null_sides = self.sides
            rows[0] = squeeze
            if joints.size:
                side_of = np.zeros(qp.n_v, dtype=np.int8)
                side_of[joints] = torque_sides
                rows[1 : 1 + n_t] = side_of[qp.dofs[qp.torque_rows]]
            if null_sides.size == qp.n_null and same:
                rows[1 + n_t :] = null_sides
        scale = self.null_scale if self.sides is not None and same else None
        return free.ravel(), rows, scale

    def match(self, p_world: FloatArray, link: IntArray) -> IntArray:
        """(N,) index of the previous contact each current one continues, -1 for new ones."""
        if self.p_world is None or self.link is None or self.link.size == 0:
            return np.full(link.size, -1, dtype=np.intp)
        return cast(
            IntArray,
            matched_contacts(
                np.ascontiguousarray(p_world, dtype=np.float64),
                np.ascontiguousarray(link, dtype=np.intp),
                np.ascontiguousarray(self.p_world, dtype=np.float64),
                np.ascontiguousarray(self.link, dtype=np.intp),
                self.match_radius**2,
            ),
        )

    def add_rows(self, torque_dofs: IntArray, null_rows: IntArray) -> None:
        """Seed the next cycle with these rows too (a cycle that ran out of time found them
        violated); the consistency rows only count while the contacts stay on the same links."""
        self.torque_dofs = np.union1d(self.torque_dofs, torque_dofs).astype(np.intp)
        self.null_rows = np.union1d(self.null_rows, null_rows).astype(np.intp)

    def same_links(self, link: IntArray) -> bool:
        """True when the contacts sit on the same links, in the same order, as last cycle."""
        # Not np.array_equal: the same test with a few microseconds less of Python, every cycle.
        last = self.link
        return last is not None and last.shape == link.shape and bool((last == link).all())


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def matched_contacts(
    p_world: FloatArray, link: IntArray, p_last: FloatArray, link_last: IntArray, r2: float
) -> IntArray:  # pragma: no cover - jit
    """(N,) index of the last cycle's contact each of the (N, 3) ``p_world`` continues: the
    nearest one on the same link, if within ``sqrt(r2)``; -1 for none (first of equals wins).
    Same links in the same order, each within the radius: the identity, without the search."""
    n, n_last = p_world.shape[0], p_last.shape[0]
    out = np.full(n, -1, dtype=np.intp)
    same = n == n_last
    for i in range(n):
        if not same:
            break
        d0 = p_world[i, 0] - p_last[i, 0]
        d1 = p_world[i, 1] - p_last[i, 1]
        d2 = p_world[i, 2] - p_last[i, 2]
        same = link[i] == link_last[i] and d0 * d0 + d1 * d1 + d2 * d2 <= r2
    if same:
        return np.arange(n)
    for i in range(n):
        best = np.inf
        for j in range(n_last):
            if link_last[j] != link[i]:
                continue
            d0 = p_world[i, 0] - p_last[j, 0]
            d1 = p_world[i, 1] - p_last[j, 1]
            d2 = p_world[i, 2] - p_last[j, 2]
            dist2 = d0 * d0 + d1 * d1 + d2 * d2
            if dist2 < best:
                best = dist2
                if dist2 <= r2:
                    out[i] = j
    return out


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def warm_edge_weights(
    match: IntArray, lam_last: FloatArray
) -> tuple[FloatArray, IntArray]:  # pragma: no cover - jit
    """The (N, 4) edge weights each contact had last cycle (``match``: the last cycle's contact
    it continues, -1 for a new one, whose weights are ``inf``) from the (N_last, 4)
    ``lam_last``, and the indices of the positive ones (``4 i + e``, increasing): the edges
    that carried force, and every edge of a new contact."""
    n, n_e = match.size, lam_last.shape[1]
    lam = np.empty((n, n_e))
    carried = np.empty(n * n_e, dtype=np.intp)
    k = 0
    for i in range(n):
        j = match[i]
        for e in range(n_e):
            v = lam_last[j, e] if j >= 0 else np.inf
            lam[i, e] = v
            if v > 0.0:
                carried[k] = n_e * i + e
                k += 1
    return lam, carried[:k]


@numba.njit(cache=CACHE, nogil=True, error_model="numpy")
def rows_of_joints(joints: IntArray, n_v: int, dofs: IntArray, torque_rows: IntArray) -> IntArray:
    """Positions in ``torque_rows`` (indices into ``dofs``) of the torque rows of the given
    joints (indices in ``[0, n_v)``; others are ignored), increasing."""
    mark = np.zeros(n_v, dtype=np.bool_)
    for j in joints:
        if 0 <= j < n_v:
            mark[j] = True
    out = np.empty(torque_rows.size, dtype=np.intp)
    k = 0
    for t in range(torque_rows.size):
        if mark[dofs[torque_rows[t]]]:
            out[k] = t
            k += 1
    return out[:k]


__all__ = ["MATCH_RADIUS", "WarmStart", "matched_contacts", "rows_of_joints", "warm_edge_weights"]
