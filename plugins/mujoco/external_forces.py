"""What the MuJoCo backend applies to bodies besides its motors (MuJoCo's ``xfrc_applied``):
the object's wrench, held until changed; a spring-damper pulling the object toward a target
pose; pushes scheduled on the object or on hand links over a window of simulated time. The
spring and the pushes are evaluated before every MuJoCo step (:meth:`ExternalForces.before_step`),
which keeps a stiff spring stable and lets a push shorter than a control period land whole.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np
import numpy.typing as npt
import pinocchio as pin

if TYPE_CHECKING:
    from .scene import HandObjectScene

FloatArray = npt.NDArray[np.float64]

Spring = tuple[FloatArray, FloatArray, FloatArray]
"""The spring's target position of the centre of mass (3,) [m], target rotation (3, 3), and
gains ``(k_lin, k_rot, d_lin, d_rot)`` (4,) [N/m, N*m/rad, N*s/m, N*m*s/rad]."""


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a x b`` of two 3-vectors, as ``np.cross`` computes it (the same products and
    differences), without its overhead (it runs before every MuJoCo step while a spring holds
    the object)."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


class ExternalForces:
    """The external forces on one scene's bodies (module docstring).

    Args:
        data: the scene's ``MjData``.
        scene: the compiled scene (the object's body and its free joint's addresses).
        com: (3,) the object's centre of mass in its frame [m].
    """

    def __init__(self, data: mujoco.MjData, scene: HandObjectScene, com: FloatArray) -> None:
        self.data, self.scene, self.com = data, scene, com
        self.clear()

    def clear(self) -> None:
        """No wrench, spring or push (a reset; MuJoCo's reset zeroes ``xfrc_applied``)."""
        self.wrench = np.zeros(6)
        """The object's wrench [N, N*m], world axes, at its centre of mass."""
        self.spring: Spring | None = None
        self.pushes: list[tuple[int, float, float, FloatArray]] = []
        """Scheduled pushes: MuJoCo body, first and end step time [s], force [N]."""
        self.pushed_links: npt.NDArray[np.intp] = np.zeros(0, dtype=np.intp)
        """Hand bodies with a scheduled push (their ``xfrc_applied`` is the pushes' alone)."""

    def set_wrench(self, wrench: FloatArray) -> None:
        """The object's wrench (6,) from now on."""
        self.wrench = wrench
        self.data.xfrc_applied[self.scene.object_body] = wrench

    def add_push(self, body: int, begin: float, end: float, force: FloatArray, link: bool) -> None:
        """Push ``body`` (a hand link's body when ``link``) with ``force`` (3,) [N] in the steps
        that start in ``[begin, end)`` [s]."""
        if link:
            self.pushed_links = np.union1d(self.pushed_links, [body]).astype(np.intp)
        self.pushes.append((body, begin, end, force))

    def clear_pushes(self) -> None:
        """Remove every scheduled push (and the force of one under way)."""
        self.pushes = []
        self.data.xfrc_applied[self.pushed_links] = 0.0
        self.pushed_links = np.zeros(0, dtype=np.intp)

    @property
    def varying(self) -> bool:
        """Whether anything must be evaluated before each step (a spring or a push)."""
        return self.spring is not None or bool(self.pushes)

    def before_step(self, t: float) -> None:
        """Set ``xfrc_applied`` for the step starting at ``t`` [s]: the object's wrench plus
        the spring's, and the pushes under way."""
        xfrc, body = self.data.xfrc_applied, self.scene.object_body
        if self.spring is not None:
            xfrc[body] = self.wrench + self.spring_wrench()
        if self.pushes:
            if self.spring is None:
                xfrc[body] = self.wrench
            xfrc[self.pushed_links] = 0.0
            for pushed, begin, end, force in self.pushes:
                if begin <= t < end:
                    xfrc[pushed, :3] += force

    def after_steps(self) -> None:
        """Between steps only the object's wrench stays applied."""
        self.data.xfrc_applied[self.scene.object_body] = self.wrench
        if self.pushes:
            self.data.xfrc_applied[self.pushed_links] = 0.0

    def spring_wrench(self) -> FloatArray:
        """(6,) the spring-damper's force and torque on the object now [N, N*m], world axes."""
        assert self.spring is not None
        p_target, R_target, (k_lin, k_rot, d_lin, d_rot) = self.spring
        d, a = self.data, self.scene.object_qpos
        flat = np.empty(9)
        mujoco.mju_quat2Mat(flat, d.qpos[a + 3 : a + 7])
        R = flat.reshape(3, 3)
        r_com = R @ self.com
        v_origin, omega = self.object_velocity()
        v_com = v_origin + _cross(omega, r_com)
        force = k_lin * (p_target - (d.qpos[a : a + 3] + r_com)) - d_lin * v_com
        torque = k_rot * pin.log3(R_target @ R.T) - d_rot * omega
        return np.concatenate((force, torque))

    def object_velocity(self) -> tuple[FloatArray, FloatArray]:
        """Linear velocity of the object frame origin [m/s] and angular velocity [rad/s], both
        in world axes."""
        a = self.scene.object_qvel
        v = self.data.qvel[a : a + 3].copy()
        R = self.data.xmat[self.scene.object_body].reshape(3, 3)
        return v, R @ self.data.qvel[a + 3 : a + 6]
