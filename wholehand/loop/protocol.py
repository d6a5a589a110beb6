"""The perturbation protocol of the paper's simulation studies (Fig. 2).

Settle; load test (a force of 0.1 m g for 1 s along +x, -x, +y, -y, +z, -z in turn); a
spring-damper wrench pulls the object toward its initial pose rotated by theta about a random
axis; the load test again. The paper gives no spring constants: ours are named below.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand import defaults

FloatArray = npt.NDArray[np.float64]

SETTLE_TIME = 0.5
"""Time the grasp settles under force regulation before any load [s]."""
ROTATION_TIME = 1.5
"""Duration of the rotational pull [s]."""
ROT_STIFFNESS = 0.3
"""Rotational spring of the pull, toward the rotated pose [N*m/rad]: 0.31 N*m at 60 deg,
about the friction torque a 10 N squeeze resists on a 5 cm object."""
ROT_DAMPING_RATIO = 1.0
"""Damping ratio of the rotational pull on the free object (damping 2 * ratio * sqrt(k I))."""
LIN_STIFFNESS = 100.0
"""Translational spring holding the object's centre at its initial place during the pull [N/m]."""
LIN_DAMPING_RATIO = 1.0
"""Damping ratio of the translational spring on the free object."""

DIRECTIONS = {
    "+x": (1.0, 0.0, 0.0), "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0), "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0), "-z": (0.0, 0.0, -1.0),
}  # fmt: skip


@dataclass(frozen=True)
class Stage:
    """One stage of the protocol."""

    name: str
    """e.g. "settle", "load +x", "rotate", "load2 -z"."""
    duration: float
    """[s]"""
    kind: str
    """"settle", "load" or "rotate"."""
    direction: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Unit load direction in the world, for load stages."""


@dataclass(frozen=True)
class PerturbationProtocol:
    """Stage sequence and the external wrench applied in each stage.

    Args:
        theta_deg: rotation of the pull target [deg]; 0 skips the pull and the second load test.
        seed: seeds the random rotation axis.
    """

    theta_deg: float = 60.0
    seed: int = 0
    settle_time: float = SETTLE_TIME
    load_fraction: float = defaults.LOAD_FRACTION_OF_WEIGHT
    load_duration: float = defaults.LOAD_DURATION
    rotation_time: float = ROTATION_TIME
    rot_stiffness: float = ROT_STIFFNESS
    rot_damping_ratio: float = ROT_DAMPING_RATIO
    lin_stiffness: float = LIN_STIFFNESS
    lin_damping_ratio: float = LIN_DAMPING_RATIO
    axis: FloatArray = field(init=False)

    def __post_init__(self) -> None:
        axis = np.random.default_rng(self.seed).standard_normal(3)
        object.__setattr__(self, "axis", axis / np.linalg.norm(axis))

    def stages(self) -> list[Stage]:
        """The stages in order."""
        out = [Stage("settle", self.settle_time, "settle")]
        loads = [Stage(f"load {n}", self.load_duration, "load", d) for n, d in DIRECTIONS.items()]
        out += loads
        if self.theta_deg > 0.0:
            out.append(Stage("rotate", self.rotation_time, "rotate"))
            out += [Stage(f"load2 {s.name[5:]}", s.duration, "load", s.direction) for s in loads]
        return out

    @property
    def duration(self) -> float:
        return float(sum(s.duration for s in self.stages()))

    def target_rotation(self, wRo_initial: FloatArray) -> FloatArray:
        """(3, 3) world orientation the pull drives the object toward."""
        return pin.exp3(np.deg2rad(self.theta_deg) * self.axis) @ wRo_initial

    def spring(
        self, mass: float, inertia: FloatArray, com: FloatArray, wMo_initial: FloatArray
    ) -> tuple[FloatArray, tuple[float, float], tuple[float, float]]:
        """Target pose (4, 4), stiffness and damping of the rotational pull (see
        :meth:`~wholehand.backends.base.PerturbableBackend.set_object_spring`).

        Args:
            mass: object mass [kg]; inertia: (3, 3) about its centre of mass [kg*m^2].
            com: (3,) centre of mass in the object frame [m].
            wMo_initial: (4, 4) the object pose at the start of the protocol.
        """
        # Rotate about the centre of mass, which the translational spring holds in place.
        target = np.eye(4)
        target[:3, :3] = self.target_rotation(wMo_initial[:3, :3])
        p_com = wMo_initial[:3, :3] @ com + wMo_initial[:3, 3]
        target[:3, 3] = p_com - target[:3, :3] @ com
        i_min = float(np.linalg.eigvalsh(inertia).min())
        damping = (
            2.0 * self.lin_damping_ratio * np.sqrt(self.lin_stiffness * mass),
            2.0 * self.rot_damping_ratio * np.sqrt(self.rot_stiffness * i_min),
        )
        return target, (self.lin_stiffness, self.rot_stiffness), damping

    def load_force(self, stage: Stage, mass: float) -> FloatArray:
        """(3,) external force on the centre of mass in a load stage, else zero [N], world axes."""
        if stage.kind != "load":
            return np.zeros(3)
        return self.load_fraction * mass * defaults.GRAVITY * np.asarray(stage.direction)
