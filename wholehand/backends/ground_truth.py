"""Ground-truth contacts, as a simulation backend reports them (``HasGroundTruth``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from wholehand.contacts.base import ContactSet
    from wholehand.models.hand import HandModel

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


@dataclass(frozen=True)
class SimContacts:
    """Hand-object contacts reported by a simulation (ground truth), as arrays in the world frame.

    Hand-hand contacts are excluded. Row i of every array is contact i.
    """

    p_world: FloatArray
    """(N, 3) contact points on the hand surface, world frame [m] (MuJoCo's contact midpoint
    moved by half the signed distance along the normal)."""
    n_world: FloatArray
    """(N, 3) unit contact normals pointing out of the object (towards the hand), world frame."""
    f_world: FloatArray
    """(N, 3) contact force exerted by the hand on the object, world frame [N]; its normal
    component is <= 0: the force points into the object."""
    link: IntArray
    """(N,) index of the touching hand link into ``HandModel.link_names``."""
    distance: FloatArray
    """(N,) signed distance between the surfaces, negative in penetration [m]."""
    geom_object: IntArray
    """(N,) the simulator's id of the object part in contact (a MuJoCo geom id)."""
    stamp: float = 0.0
    """Simulation time [s]."""

    def __len__(self) -> int:
        return int(self.p_world.shape[0])

    @property
    def f_normal(self) -> FloatArray:
        """(N,) normal force magnitudes on the object [N] (>= 0)."""
        f_normal: FloatArray = -np.einsum("ij,ij->i", self.f_world, self.n_world)
        return f_normal

    def to_contact_set(self, hand: HandModel) -> ContactSet:
        """The contacts as a :class:`wholehand.contacts.base.ContactSet` (forces dropped)."""
        from wholehand.contacts.base import ContactSet

        return ContactSet(
            p_world=self.p_world.copy(),
            n_world=self.n_world.copy(),
            link=self.link.copy(),
            distance=self.distance.copy(),
            link_actuated=np.asarray(hand.link_actuated, dtype=bool),
            link_fingertip=np.asarray(hand.link_fingertip, dtype=bool),
            stamp=self.stamp,
        )
