"""Contact sets and the contact-estimator interface (paper Sec. III-B)."""

from __future__ import annotations

import abc
import dataclasses
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
    p_joint: FloatArray | None = None
    """(N, 3) the same points in the frame of the joint carrying their link [m]; None until
    :meth:`in_joint_frames` fills it (estimators may leave it out)."""
    n_joint: FloatArray | None = None
    """(N, 3) the normals in the same joint frames (set together with ``p_joint``)."""
    joint: IntArray | None = None
    """(N,) Pinocchio joint carrying each contact's link (set together with ``p_joint``)."""

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
        if (self.p_joint is None) != (self.joint is None) or (
            (self.p_joint is None) != (self.n_joint is None)
        ):
            raise ConfigError("ContactSet: give p_joint, n_joint and joint together, or none")
        if self.p_joint is not None:
            assert self.n_joint is not None and self.joint is not None
            for name, got, want in (
                ("p_joint", self.p_joint.shape, (n, 3)),
                ("n_joint", self.n_joint.shape, (n, 3)),
                ("joint", self.joint.shape, (n,)),
            ):
                if got != want:
                    raise ConfigError(f"ContactSet.{name} has shape {got}, expected {want}")
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
        has_joint = self.p_joint is not None
        return ContactSet(
            p_world=self.p_world[mask],
            n_world=self.n_world[mask],
            link=self.link[mask],
            distance=self.distance[mask],
            link_actuated=self.link_actuated,
            link_fingertip=self.link_fingertip,
            stamp=self.stamp,
            p_joint=self.p_joint[mask] if has_joint else None,  # type: ignore[index]
            n_joint=self.n_joint[mask] if has_joint else None,  # type: ignore[index]
            joint=self.joint[mask] if has_joint else None,  # type: ignore[index]
        )

    def transformed(self, M: FloatArray) -> ContactSet:
        """The set moved rigidly by the world transform ``M`` (4, 4): points and normals (the
        joint-frame copies are dropped: they no longer match)."""
        R, t = M[:3, :3], M[:3, 3]
        return dataclasses.replace(
            self,
            p_world=self.p_world @ R.T + t,
            n_world=self.n_world @ R.T,
            p_joint=None,
            n_joint=None,
            joint=None,
        )

    def in_joint_frames(self, kinematics: HandKinematics) -> ContactSet:
        """The set with ``p_joint``, ``n_joint`` and ``joint`` filled from the kinematics the
        contacts were found at (kept as they are when already filled)."""
        if self.p_joint is not None:
            return self
        joint = kinematics.hand.link_joint[self.link].astype(np.intp)
        p_joint, n_joint = kinematics.to_joint_frames(self.p_world, self.n_world, joint)
        return dataclasses.replace(self, p_joint=p_joint, n_joint=n_joint, joint=joint)

    def moved_to(self, kinematics: HandKinematics) -> ContactSet:
        """The contacts carried with their links to the configuration of ``kinematics``: each
        point and normal stays fixed in its joint frame (needs :meth:`in_joint_frames`)."""
        if self.p_joint is None or self.n_joint is None or self.joint is None:
            raise ConfigError(
                "ContactSet.moved_to needs the contacts in their joint frames; call "
                "in_joint_frames(kinematics at the configuration they were found at) first"
            )
        p_world, n_world = kinematics.from_joint_frames(self.p_joint, self.n_joint, self.joint)
        return dataclasses.replace(self, p_world=p_world, n_world=n_world)

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

    def preload(self, kinematics: HandKinematics, wMo: FloatArray) -> None:
        r"""Load now what a first estimate would load in a control cycle (a compiled kernel, a
        lazily built structure); the control loop calls it once, before its first cycle. The
        default estimates once and :meth:`reset`\ s.

        Args:
            kinematics: Hand kinematics updated to the loop's first joint reading.
            wMo: (4, 4) an object pose in the world (the loop gives the world origin: what the
                controller sees of the object comes through its filters, in the cycles).
        """
        self.estimate(kinematics, wMo)
        self.reset()

    def reset(self) -> None:  # noqa: B027 - an optional hook, stateless estimators keep it
        """Forget what earlier cycles left (the contacts kept for the next selection); called
        after :meth:`preload` and when a grasp starts afresh."""
