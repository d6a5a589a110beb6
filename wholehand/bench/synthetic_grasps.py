"""Seeded synthetic grasps shaped like the paper's (Sec. IV-C, K sweep: 14 to 91 contacts), for
``wholehand bench allocate`` and the allocation tests.

A 16-DoF hand of four 4-joint fingers (revolute joints with random axes, their origins 7 cm from
the object's centre) and a passive palm; contacts lie on a 4 cm sphere around the COM, clustered
per link (up to ``K = max(5, ceil(N / 17))`` per link), with the sphere's outward normals. The
Jacobian of a contact on link k of a finger has the columns ``z_j x (p - o_j)`` of that finger's
joints 0..k and zeros elsewhere (block-sparse, one chain per finger); palm contacts are passive.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast

import numpy as np
import numpy.typing as npt

from wholehand.contacts.base import ContactSet

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


@dataclass(frozen=True)
class SyntheticHand:
    """A block-sparse stand-in hand: link 0 is the palm, then ``dofs`` links per finger."""

    n_fingers: int
    """Fingers (kinematic chains)."""
    dofs: int
    """Joints (and links) per finger."""
    joint_origin: FloatArray
    """(n_v, 3) a point on each joint axis, world frame [m]."""
    joint_axis: FloatArray
    """(n_v, 3) unit joint axes, world axes."""
    link_direction: FloatArray
    """(L, 3) unit direction from the COM where each link's contacts cluster."""

    @property
    def n_v(self) -> int:
        return self.n_fingers * self.dofs

    @property
    def n_links(self) -> int:
        return 1 + self.n_v

    @property
    def link_actuated(self) -> npt.NDArray[np.bool_]:
        """(L,) every finger link is actuated, the palm is not."""
        out = np.ones(self.n_links, dtype=bool)
        out[0] = False
        return out

    @property
    def link_fingertip(self) -> npt.NDArray[np.bool_]:
        """(L,) the last link of each finger."""
        out = np.zeros(self.n_links, dtype=bool)
        out[self.dofs :: self.dofs] = True
        return out

    def jacobians(self, link: IntArray, p_world: FloatArray) -> FloatArray:
        """(N, 3, n_v) point Jacobians of contacts at ``p_world`` (N, 3) on links ``link``."""
        n = link.size
        cross = np.cross(self.joint_axis[None, :, :], p_world[:, None, :] - self.joint_origin)
        finger_link = link - 1  # -1 for the palm
        j = np.arange(self.n_v)
        same_finger = (finger_link[:, None] // self.dofs) == (j[None, :] // self.dofs)
        proximal = (j[None, :] % self.dofs) <= (finger_link[:, None] % self.dofs)
        mask = (finger_link[:, None] >= 0) & same_finger & proximal
        return cast(
            FloatArray, (cross * mask[:, :, None]).transpose(0, 2, 1).reshape(n, 3, self.n_v)
        )


def synthetic_hand(
    rng: np.random.Generator, n_fingers: int = 4, dofs: int = 4, reach: float = 0.07
) -> SyntheticHand:
    """A random :class:`SyntheticHand` (joint origins at ``reach`` [m] from the COM)."""
    n_v = n_fingers * dofs
    origin = rng.normal(size=(n_v, 3))
    origin *= reach / np.linalg.norm(origin, axis=1, keepdims=True)
    axis = rng.normal(size=(n_v, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    direction = rng.normal(size=(1 + n_v, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return SyntheticHand(n_fingers, dofs, origin, axis, direction)


@dataclass(frozen=True)
class SyntheticGrasp:
    """Nominal contacts of one synthetic grasp."""

    hand: SyntheticHand
    link: IntArray
    """(N,) link of each contact."""
    direction: FloatArray
    """(N, 3) unit direction of each contact from the COM (= outward normal)."""
    radius: float
    """Object radius [m]."""
    p_com_world: FloatArray
    """(3,) object COM [m]."""

    def cycle(
        self, rng: np.random.Generator | None = None, jitter: float = 0.0
    ) -> tuple[ContactSet, FloatArray, FloatArray]:
        """``(contacts, J_world, p_com_world)`` with points jittered by ``jitter`` [m] (std)."""
        p = self.p_com_world + self.radius * self.direction
        if rng is not None and jitter > 0.0:
            p = p + jitter * rng.normal(size=p.shape)
        r = p - self.p_com_world
        n = r / np.linalg.norm(r, axis=1, keepdims=True)
        contacts = ContactSet(
            p_world=p,
            n_world=n,
            link=self.link,
            distance=np.zeros(self.link.size),
            link_actuated=self.hand.link_actuated,
            link_fingertip=self.hand.link_fingertip,
        )
        return contacts, self.hand.jacobians(self.link, p), self.p_com_world.copy()


def synthetic_grasp(
    seed: int, n_contacts: int, radius: float = 0.04, spread: float = 0.25
) -> SyntheticGrasp:
    """A seeded random grasp of ``n_contacts`` contacts on a :func:`synthetic_hand`.

    Args:
        seed: Seed of everything random.
        n_contacts: N.
        radius: Sphere radius [m].
        spread: Std of the per-contact direction around its link's direction [-] (~rad).
    """
    rng = np.random.default_rng(seed)
    hand = synthetic_hand(rng)
    k_max = max(5, math.ceil(n_contacts / hand.n_links))
    counts = np.zeros(hand.n_links, dtype=np.intp)
    for _ in range(n_contacts):
        counts[rng.choice(np.flatnonzero(counts < k_max))] += 1
    link = np.repeat(np.arange(hand.n_links), counts).astype(np.intp)
    d = hand.link_direction[link] + spread * rng.normal(size=(n_contacts, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return SyntheticGrasp(hand, link, d, radius, np.zeros(3))


__all__ = ["SyntheticGrasp", "SyntheticHand", "synthetic_grasp", "synthetic_hand"]
