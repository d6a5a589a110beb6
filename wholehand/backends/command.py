"""What a stage sends to the robot each cycle: joint torques and/or joint targets per joint group.

A torque-controlled group (the hand under force regulation) gets torques; a position-controlled
group (an arm, a held finger) gets targets that the backend tracks with its own servo at its own
rate, as a joint position controller does:

    tau_j = tau_ff_j + kp_j (q*_j - q_j) + kd_j (dq*_j - dq_j),   clamped to the joint's limit,

evaluated at every simulation step (MuJoCo) or in the drive (hardware). Joints a group does not
name get ``tau`` of the command. A backend may instead servo a hand's groups in the controller, at
the control rate (:data:`HAND_SERVOS`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from wholehand.errors import ConfigError
from wholehand.models.poses import check_pose

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

HAND_SERVOS = ("step", "command")
"""Where a backend evaluates the hand's target groups: ``"step"`` at every simulation step (the
drives), ``"command"`` once per command on the state when it is applied, the torque then held
(a servo in the controller at the control rate, as the robot controller runs a hand without a
position interface)."""


@dataclass(frozen=True)
class JointTargets:
    """Position and/or velocity targets with gains for one group of joints (m of them)."""

    dofs: IntArray
    """(m,) velocity indices of the group's joints (Pinocchio order)."""
    q: FloatArray | None
    """(m,) target positions [rad or m]; None: velocity control only (no position term)."""
    dq: FloatArray | None
    """(m,) target velocities [rad/s]; None: zero (the damping term brakes)."""
    kp: FloatArray
    """(m,) position gains [N*m/rad]."""
    kd: FloatArray
    """(m,) velocity gains [N*m*s/rad]."""
    name: str = ""
    """The group's name (e.g. ``"arm"``), for records and errors."""

    def __post_init__(self) -> None:
        dofs = np.asarray(self.dofs, dtype=np.intp).reshape(-1)
        m = dofs.shape[0]
        object.__setattr__(self, "dofs", dofs)
        for key in ("q", "dq", "kp", "kd"):
            value = getattr(self, key)
            if value is None and key in ("q", "dq"):
                continue
            if isinstance(value, np.ndarray) and value.dtype == np.float64 and value.shape == (m,):
                arr = value.copy()  # the common case, without broadcast_to's cost
            else:
                arr = np.broadcast_to(np.asarray(value, dtype=float), (m,)).copy()
            if not np.isfinite(arr).all() or (key in ("kp", "kd") and (arr < 0.0).any()):
                raise ConfigError(
                    f"JointTargets {self.name!r}: {key} must be finite"
                    + (" and >= 0" if key in ("kp", "kd") else "")
                    + f", got {arr.tolist()}"
                )
            object.__setattr__(self, key, arr)
        if self.q is None and self.dq is None:
            raise ConfigError(f"JointTargets {self.name!r}: give q, dq or both")
        if len(set(dofs.tolist())) != m:
            raise ConfigError(f"JointTargets {self.name!r}: dofs repeat a joint: {dofs.tolist()}")


@dataclass(frozen=True)
class Command:
    """One cycle's command to every joint."""

    tau: FloatArray
    """(n_v,) joint torques [N*m]; on joints of a target group, a feedforward term."""
    targets: tuple[JointTargets, ...] = field(default_factory=tuple)
    """Position-controlled groups (disjoint)."""
    base: FloatArray | None = None
    """(4, 4) pose to move the hand base to, world frame, for a hand on a floating wrist
    (the MuJoCo backend's ``base="floating"`` or ``"mocap"``); None: the base stays where it
    is."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "tau", np.asarray(self.tau, dtype=float))
        seen: set[int] = set()
        for group in self.targets:
            overlap = seen & set(group.dofs.tolist())
            if overlap:
                raise ConfigError(
                    f"Command: joint groups overlap on dofs {sorted(overlap)} (group "
                    f"{group.name!r}); each joint belongs to one group"
                )
            seen |= set(group.dofs.tolist())
        if self.base is not None:
            object.__setattr__(self, "base", check_pose(self.base, "Command.base"))
        n_v = self.tau.shape[0]
        if seen and (min(seen) < 0 or max(seen) >= n_v):
            raise ConfigError(f"Command: target dofs {sorted(seen)} outside [0, {n_v})")

    @classmethod
    def torques(cls, tau: npt.ArrayLike) -> Command:
        """Torques only (every joint torque-controlled)."""
        return cls(np.asarray(tau, dtype=float))

    def target_mask(self) -> npt.NDArray[np.bool_]:
        """(n_v,) True for joints under a target group."""
        mask = np.zeros(self.tau.shape[0], dtype=bool)
        for group in self.targets:
            mask[group.dofs] = True
        return mask
