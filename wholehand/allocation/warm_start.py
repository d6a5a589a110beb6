"""What one allocation leaves for the next: its solution and binding rows, by contact identity.

Warm start (:class:`WarmStart`, driven by the allocator). The torque rows binding last cycle (by
joint) and, when the contacts sit on the same links in the same order, the consistency rows
binding last cycle (by basis index) seed the working set, which saves screening rounds. Solvers
that use a primal start (OSQP, qpsolvers) get the previous edge weights, each contact matched to
the previous contact on the same link with the nearest point (within ``match_radius``). DAQP
instead restarts from its own previous working set. Measured effect (``wholehand bench
allocate``): large where rows bind (fewer rounds) and for OSQP; none for PIQP (interior point).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import cast

import numpy as np
import numpy.typing as npt

from wholehand.allocation.kernels import matched_contacts

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

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

    def clear(self) -> None:
        """Forget everything."""
        self.p_world = self.link = self.lam = None
        self.torque_dofs = np.zeros(0, dtype=np.intp)
        self.null_rows = np.zeros(0, dtype=np.intp)

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


__all__ = ["MATCH_RADIUS", "WarmStart"]
