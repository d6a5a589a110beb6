"""The reacher interface: the next hand configuration on the way to a grasp (paper Sec. III-D)."""

from __future__ import annotations

import abc
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ReachTargets:
    """Where the reacher brings the hand this cycle, world frame.

    Attributes:
        links: link name -> (4, 4) target pose of that link (fingertips and palm) [m].
        q: (n_q,) target joint angles [rad] (the posture task's, e.g. the grasp's).
        palm: the palm link's name among ``links`` (its weight stays fixed; the fingertips'
            rise as the palm nears its target).
        avoid_object: keep the hand clear of the object (False at the grasp stage, where the
            fingers must touch it).
    """

    links: dict[str, FloatArray]
    q: FloatArray
    palm: str
    avoid_object: bool = True
    meta: dict[str, float] = field(default_factory=dict)


class Reacher(abc.ABC):
    """Moves a hand on a floating wrist toward target link poses, one control period at a time.

    Registered in the ``wholehand.reachers`` entry-point group; constructed with the keywords
    ``hand`` (:class:`~wholehand.models.hand.HandModel`), ``obj``
    (:class:`~wholehand.models.objects.ObjectModel`), ``table``
    (:class:`~wholehand.backends.table.Table` or None) and the reacher's own options.
    """

    @abc.abstractmethod
    def step(
        self, q: FloatArray, wMb: FloatArray, wMo: FloatArray, targets: ReachTargets, dt: float
    ) -> tuple[FloatArray, FloatArray]:
        """The configuration one period ahead: ``(q_next (n_q,) [rad], wMb_next (4, 4))``.

        Args:
            q: (n_q,) current joint angles, Pinocchio order [rad].
            wMb: (4, 4) current pose of the hand base in the world.
            wMo: (4, 4) object pose in the world (the tracked one).
            targets: the targets of this cycle.
            dt: control period [s].
        """

    def fault_counts(self) -> dict[str, int]:
        """The steps this reacher could not take as asked, by kind (none by default; e.g. the
        ``mink`` reacher's ``relaxed`` and ``held``)."""
        return {}
