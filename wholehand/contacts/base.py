"""Contact sets and the contact-estimator interface (paper Sec. III-B)."""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from wholehand.errors import ConfigError

if TYPE_CHECKING:
    from wholehand.models.kinematics import HandKinematics

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class ContactSet:
    """Estimated hand-object contacts of one control cycle, as arrays in the world frame.

    Row i of every per-contact array describes contact i. Empty sets (N = 0) are valid.
    """

    p_world: FloatArray
    """(N, 3) contact points on the hand surface, world frame [m]."""
    n_world: FloatArray
    """(N, 3) unit object-surface normals at the contacts, out of the object, world frame."""
    link: IntArray
    """(N,) index of the hand link carrying each contact, into ``HandModel.link_names``."""
    distance: FloatArray
    """(N,) signed distance of each hand point to the object surface, negative inside [m]."""
    link_actuated: BoolArray
    """(L,) per hand link: True when forces on it are produced by actuated joints."""
    link_fingertip: BoolArray
    """(L,) per hand link: True for distal (fingertip) links."""
    stamp: float = 0.0
    """Time of the state the set was computed from [s]."""
    frame: str = field(default="world")
    """Frame of every position and normal; always ``"world"``."""

    def __post_init__(self) -> None:
        n = self.p_world.shape[0]
        shapes = {
            "p_world": (self.p_world.shape, (n, 3)),
            "n_world": (self.n_world.shape, (n, 3)),
            "link": (self.link.shape, (n,)),
            "distance": (self.distance.shape, (n,)),
        }
        for name, (got, want) in shapes.items():
            if got != want:
                raise ConfigError(f"ContactSet.{name} has shape {got}, expected {want}")
        if self.link_actuated.shape != self.link_fingertip.shape:
            raise ConfigError(
                "ContactSet.link_actuated and link_fingertip must both have shape (L,), got "
                f"{self.link_actuated.shape} and {self.link_fingertip.shape}"
            )
        if n and (self.link.min() < 0 or self.link.max() >= self.link_actuated.shape[0]):
            raise ConfigError(
                f"ContactSet.link holds indices outside [0, {self.link_actuated.shape[0]})"
            )

    def __len__(self) -> int:
        return int(self.p_world.shape[0])

    @property
    def actuated(self) -> BoolArray:
        """(N,) True for contacts on actuated links."""
        return self.link_actuated[self.link]

    @property
    def fingertip(self) -> BoolArray:
        """(N,) True for contacts on fingertip links."""
        return self.link_fingertip[self.link]

    def select(self, mask: BoolArray | IntArray) -> ContactSet:
        """The subset of contacts picked by a boolean mask or an index array."""
        return ContactSet(
            p_world=self.p_world[mask],
            n_world=self.n_world[mask],
            link=self.link[mask],
            distance=self.distance[mask],
            link_actuated=self.link_actuated,
            link_fingertip=self.link_fingertip,
            stamp=self.stamp,
        )

    @classmethod
    def empty(
        cls, link_actuated: BoolArray, link_fingertip: BoolArray, stamp: float = 0.0
    ) -> ContactSet:
        """A set with no contacts for a hand with the given per-link flags."""
        return cls(
            p_world=np.zeros((0, 3)),
            n_world=np.zeros((0, 3)),
            link=np.zeros(0, dtype=np.intp),
            distance=np.zeros(0),
            link_actuated=link_actuated,
            link_fingertip=link_fingertip,
            stamp=stamp,
        )


class ContactEstimator(abc.ABC):
    """Turns a hand state and an object pose into a :class:`ContactSet`.

    Implementations are constructed with the hand and object models (and their own keyword
    parameters) and registered in the ``wholehand.contact_estimators`` entry-point group.
    """

    @abc.abstractmethod
    def estimate(
        self, kinematics: HandKinematics, wMo: FloatArray, stamp: float = 0.0
    ) -> ContactSet:
        """Contacts between the hand and the object.

        Args:
            kinematics: Hand kinematics already updated to the current q and base pose.
            wMo: (4, 4) pose of the object frame in the world.
            stamp: Time of the state [s], copied into the result.
        """
