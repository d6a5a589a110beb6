"""The ``mujoco`` backend: a hand and a free object simulated in MuJoCo.

The scene (its contact model, timestep, friction combination and the MuJoCo/Pinocchio index maps)
is built by :mod:`wholehand_plugins.mujoco.scene`; this module wraps it in the
:class:`~wholehand.backends.base.Backend` interface. Every array crossing this interface is in
Pinocchio joint order and world-frame 4x4 poses ``aMb``; MuJoCo's own order never leaks out.
"""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np
import numpy.typing as npt

from wholehand.backends.base import (
    Backend,
    HasGroundTruth,
    PushesBodies,
    PushesObject,
    ReportsWarnings,
    Resettable,
)
from wholehand.backends.command import HAND_SERVOS, Command
from wholehand.backends.ground_truth import SimContacts
from wholehand.backends.observation import HISTORY_SAMPLES, JointHistory, Observation
from wholehand.backends.table import TABLE_GEOM
from wholehand.errors import ConfigError
from wholehand.models.poses import check_pose

from .contacts import hand_object_contacts, warning_counts
from .external_forces import ExternalForces
from .poses import mujoco_quat, pose_from_mujoco
from .scene import HandObjectScene, build_scene
from .scene_options import (
    DEFAULT_TIMESTEP,
    HAND_BIT,
    OBJECT_BIT,
    TABLE_BIT,
    WRIST_JOINT,
    WRIST_TARGET,
    SceneOptions,
)
from .servo import PDTerms, check_arm_servo, pd_terms, pd_torque, terms_of
from .step_guard import StepGuard

if TYPE_CHECKING:
    from wholehand.models.hand import HandModel
    from wholehand.models.objects import ObjectModel

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

_WARNING_MEANING = {
    "bad_qacc": "the simulation diverged and MuJoCo reset it; lower the timestep or stiffen "
    "the contacts",
    "step_retries": "a step's contact solve failed and was taken again with frictionless "
    "hand-hand contacts (wholehand_plugins.mujoco.step_guard)",
    "step_retries_failed": "a retried step still ended too fast; the simulation may diverge",
}
"""What a warning of :meth:`MujocoBackend.warnings` means, for the log."""

_STEP_EPS = 1e-9
"""Relative slack so that e.g. a 5 ms duration at 1 ms is 5 steps, not 6 (float rounding)."""


def _vector(value: Any, n: int, name: str) -> FloatArray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (n,):
        raise ConfigError(f"MujocoBackend: {name} must have shape ({n},), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ConfigError(f"MujocoBackend: {name} contains NaN or inf: {arr.tolist()}")
    return arr


class MujocoBackend(
    Backend, PushesObject, PushesBodies, HasGroundTruth, Resettable, ReportsWarnings
):
    """MuJoCo simulation of a mounted hand and a free object (torques and joint targets).

    Args:
        hand: a :class:`~wholehand.models.hand.HandModel` or the name/path of a hand.
        obj: an :class:`~wholehand.models.objects.ObjectModel` or an object spec accepted by
            :func:`~wholehand.models.object_catalogue.load_object` (e.g. ``"077_rubiks_cube"``).
        wMo_init: (4, 4) initial pose of the object frame in the world; default: 0.5 m below the
            hand base, clear of the hand.
        q_init: (n_q,) initial joint positions, Pinocchio order; default ``hand.neutral()``.
        gravity: gravity (0, 0, -9.81) m/s^2 when True; off by default as in the paper.
        timestep: simulation step [s] (default 1 ms).
        history: joint samples kept for :meth:`Observation.q_at` (one per :meth:`observe`).
        wMb: (4, 4) pose of the hand base in the world; default: the mount pose ``hand.wMb``.
        hand_servo: where the hand's target groups are servoed: ``"step"``, a PD law before
            every MuJoCo step on that step's state (a servo in the drives); ``"command"``, once
            when the command is applied, on the state then, held until the next (a servo in
            the controller at the control rate, as the robot controller runs a hand without a
            position interface). An arm's targets are servoed every step either way.
        **options: further :class:`~wholehand_plugins.mujoco.scene_options.SceneOptions` fields
            (``cone``, ``impratio``, ``condim``, ``friction``, ``solref``, ``solimp``, ``base``,
            ``self_collision``, ``collision``, ``coacd``, ``iterations``, ``visual_mesh``).

    Attributes:
        scene: the compiled scene and its index maps; ``scene.model`` is the ``MjModel``.
        data: the ``MjData``.
    """

    def __init__(
        self,
        hand: HandModel | str,
        obj: ObjectModel | str,
        wMo_init: FloatArray | None = None,
        q_init: FloatArray | None = None,
        gravity: bool = False,
        timestep: float = DEFAULT_TIMESTEP,
        wMb: FloatArray | None = None,
        history: int = HISTORY_SAMPLES,
        hand_servo: str = "step",
        **options: Any,
    ) -> None:
        if isinstance(hand, str):
            from wholehand.models.hand import load_hand

            hand = load_hand(hand)
        if isinstance(obj, str):
            from wholehand.models.object_catalogue import load_object

            obj = load_object(obj)
        fields = set(SceneOptions.__dataclass_fields__) - {"gravity", "timestep"}
        unknown = sorted(set(options) - fields)
        if unknown:
            raise ConfigError(
                f"MujocoBackend: unknown options {unknown}; valid options: {sorted(fields)}"
            )
        if hand_servo not in HAND_SERVOS:
            raise ConfigError(
                f"MujocoBackend: hand_servo must be one of {HAND_SERVOS}, got {hand_servo!r}"
            )
        self.hand_servo = hand_servo
        self.hand = hand
        self.obj = obj
        opts = SceneOptions(gravity=bool(gravity), timestep=timestep, **options)
        check_arm_servo(hand, opts.timestep)
        self.scene: HandObjectScene = build_scene(hand, obj, wMo_init, opts, wMb)
        self.model = self.scene.model
        dofs = np.flatnonzero(self.scene.ctrl_index >= 0)
        limit = self.scene.tau_max[dofs]
        self._ctrl_map = (dofs, self.scene.ctrl_index[dofs], -limit, limit)
        """Joints with a motor, their MuJoCo actuators and torque bounds [N*m]."""
        self.data = mujoco.MjData(self.model)
        self._guard = StepGuard(self.model, self.model.geom_contype == HAND_BIT)
        self._warned: set[str] = set()
        self._warnings_seen = 0
        self.history = JointHistory(hand.nq, history)
        self._wrist_q = -1
        if opts.base == "floating":
            self._wrist_q = int(self.model.joint(WRIST_JOINT).qposadr[0])
        self._targets: PDTerms | None = None
        self._forces = ExternalForces(self.data, self.scene, obj.com)
        wMo = self.object_pose_in_model() if wMo_init is None else wMo_init
        self.reset(hand.neutral() if q_init is None else q_init, wMo)

    # --- Backend interface --------------------------------------------------------------------
    def observe(self) -> Observation:
        """Joint positions and velocities (Pinocchio order), base and object poses, all stamped
        with the simulation time; the joint sample is added to :attr:`history` (once per time)."""
        d, s = self.data, self.scene
        t = self.time
        a = s.object_qpos
        q = d.qpos[s.qpos_index].copy()
        wMb = self._base_pose()
        if not len(self.history) or self.history.newest_stamp < t:
            self.history.push(t, q, wMb)
        # From qpos, not xpos: after mj_step, xpos still holds the pose before the integration.
        return Observation(
            q=q,
            dq=d.qvel[s.qvel_index].copy(),
            wMb=wMb,
            stamp_q=t,
            wMo=pose_from_mujoco(d.qpos[a : a + 3], d.qpos[a + 3 : a + 7]),
            stamp_object=t,
            history=self.history,
        )

    def _base_pose(self) -> FloatArray:
        m, body = self.model, self.scene.base_body
        if self._wrist_q >= 0:  # a floating base: its free joint
            a = self._wrist_q
            return pose_from_mujoco(self.data.qpos[a : a + 3], self.data.qpos[a + 3 : a + 7])
        mocap = int(m.body_mocapid[body])
        if mocap >= 0:
            return pose_from_mujoco(self.data.mocap_pos[mocap], self.data.mocap_quat[mocap])
        return pose_from_mujoco(m.body_pos[body], m.body_quat[body])

    def apply(self, command: Command) -> None:
        """Send joint torques [N*m] (Pinocchio order) and joint targets, held until the next
        command. Torques are clipped to +-tau_max; entries of joints that are not actuated are
        ignored. A target group's PD law (:mod:`wholehand.backends.command`) is evaluated before
        every MuJoCo step on the state of that step."""
        tau = _vector(command.tau, self.hand.nv, "tau")
        if command.base is not None:
            self.set_base_pose(command.base)
        self._tau = tau
        self._targets = None
        if command.targets:
            self._targets = pd_terms(command)
            if self.hand_servo == "command":
                self._hold_hand_servo()
        self._set_ctrl(self._tau if self._targets is None else self._pd_torque())

    def _hold_hand_servo(self) -> None:
        """Evaluate the hand joints' PD terms now into the held torque; only the arm's stay
        servoed every step."""
        assert self._targets is not None
        self._tau = np.where(self.hand.arm_dofs, self._tau, self._pd_torque())
        self._targets = terms_of(self._targets, self.hand.arm_dofs)

    def _set_ctrl(self, tau: FloatArray) -> None:
        dofs, ctrl, lower, upper = self._ctrl_map
        self.data.ctrl[ctrl] = np.minimum(np.maximum(tau[dofs], lower), upper)  # np.clip, leaner

    def _pd_torque(self) -> FloatArray:
        """The commanded torques with every target group's PD term at the current state."""
        assert self._targets is not None
        d, s = self.data, self.scene
        return pd_torque(self._tau, self._targets, d.qpos[s.qpos_index], d.qvel[s.qvel_index])

    def step(self, duration: float) -> None:
        """Advance the simulation by ``ceil(duration / timestep)`` steps (0 for duration 0).
        Each step goes through :class:`~wholehand_plugins.mujoco.step_guard.StepGuard`: one whose
        contact solve failed is taken again (counted in :meth:`warnings`)."""
        if not (math.isfinite(duration) and duration >= 0.0):
            raise ConfigError(f"MujocoBackend.step: duration must be >= 0 [s], got {duration!r}")
        n = math.ceil(duration / self.model.opt.timestep - _STEP_EPS)
        t_before = float(self.data.time)
        forces = self._forces
        for _ in range(n):
            if forces.varying:
                forces.before_step(self.time)
            if self._targets is not None:
                self._set_ctrl(self._pd_torque())
            self._guard.step(self.data)
        forces.after_steps()
        if n > 0:
            if self.data.time < t_before:  # MuJoCo diverged and reset its data, time included
                self._time_offset += t_before + n * self.model.opt.timestep - self.data.time
            self._check_warnings()

    @property
    def time(self) -> float:
        """Simulation time [s]: MuJoCo's, kept running when a divergence makes MuJoCo reset its
        data (and its clock) to the initial state, so the schedule of a run never goes back."""
        return float(self.data.time) + self._time_offset

    def apply_object_wrench(self, force_world: FloatArray, torque_world: FloatArray) -> None:
        """Apply a force [N] and torque [N*m], world axes, at the object's centre of mass; held
        until changed (MuJoCo ``xfrc_applied``)."""
        force = _vector(force_world, 3, "force_world")
        torque = _vector(torque_world, 3, "torque_world")
        self._forces.set_wrench(np.concatenate((force, torque)))

    def set_object_spring(
        self,
        wMo_target: FloatArray | None,
        stiffness: tuple[float, float] = (0.0, 0.0),
        damping: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        """Spring-damper toward ``wMo_target`` on the object's centre of mass, evaluated before
        every MuJoCo step and added to the wrench of :meth:`apply_object_wrench`; None removes it.
        Stiffness: [N/m], [N*m/rad]; damping: [N*s/m], [N*m*s/rad]."""
        if wMo_target is None:
            self._forces.spring = None
            return
        target = check_pose(wMo_target, "wMo_target")
        gains = np.asarray([*stiffness, *damping], dtype=float)
        if gains.shape != (4,) or not np.all(np.isfinite(gains)) or np.any(gains < 0.0):
            raise ConfigError(
                f"MujocoBackend.set_object_spring: stiffness and damping must be two finite "
                f"values >= 0 each, got {stiffness!r} and {damping!r}"
            )
        p_com = target[:3, :3] @ self.obj.com + target[:3, 3]
        self._forces.spring = (p_com, target[:3, :3].copy(), gains)

    def schedule_push(
        self, force_world: FloatArray, start: float, duration: float, link: str | None = None
    ) -> None:
        """Push the object (``link`` None) or the hand link ``link`` with ``force_world`` (3,)
        [N], world axes, at its centre of mass, in the MuJoCo steps that start in ``[start,
        start + duration)`` [s] (half a step of tolerance at each end: ``round(duration /
        timestep)`` steps). Added to ``xfrc_applied`` beside the object's wrench and spring."""
        force = _vector(force_world, 3, "force_world")
        if not (math.isfinite(start) and math.isfinite(duration) and duration > 0.0):
            raise ConfigError(
                f"MujocoBackend.schedule_push: start must be finite and duration > 0 [s], got "
                f"start={start!r}, duration={duration!r}"
            )
        if link is None:
            body = self.scene.object_body
        else:
            if link not in self.hand.link_names:
                raise ConfigError(
                    f"MujocoBackend.schedule_push: {link!r} is not a link of hand "
                    f"{self.hand.name!r}; use one of {self.hand.link_names}"
                )
            body = int(self.scene.link_body[self.hand.link_index(link)])
        half = 0.5 * self.timestep
        self._forces.add_push(body, start - half, start + duration - half, force, link is not None)

    def clear_pushes(self) -> None:
        """Remove every scheduled push (and the force of one under way)."""
        self._forces.clear_pushes()

    # --- extras -------------------------------------------------------------------------------
    @property
    def timestep(self) -> float:
        """Simulation step [s]."""
        return float(self.model.opt.timestep)

    def reset(self, q: FloatArray, wMo: FloatArray, wMb: FloatArray | None = None) -> None:
        """Restart at time 0 with joint positions ``q`` (n_q,) (Pinocchio order), object pose
        ``wMo`` (4, 4), zero velocities, torques and external wrench. ``wMb`` moves a mocap base."""
        q = _vector(q, self.hand.nq, "q")
        wMo = check_pose(wMo, "wMo")
        d, s = self.data, self.scene
        mujoco.mj_resetData(self.model, d)
        self.history.clear()
        self._time_offset = 0.0
        self._tau = np.zeros(self.hand.nv)
        self._targets = None
        self._forces.clear()
        d.qpos[s.qpos_index] = q
        d.qpos[s.object_qpos : s.object_qpos + 3] = wMo[:3, 3]
        d.qpos[s.object_qpos + 3 : s.object_qpos + 7] = mujoco_quat(wMo)
        if self._wrist_q >= 0:  # a floating base starts on its target
            start = self._base_pose() if wMb is None else check_pose(wMb, "wMb")
            d.qpos[self._wrist_q : self._wrist_q + 3] = start[:3, 3]
            d.qpos[self._wrist_q + 3 : self._wrist_q + 7] = mujoco_quat(start)
            wMb = start
        if wMb is not None:
            self.set_base_pose(wMb)
        mujoco.mj_forward(self.model, d)
        self._warned.clear()
        self._warnings_seen = 0
        self._guard.clear()

    def set_kinematic_hand(self, q: FloatArray) -> None:
        """Set joint positions ``q`` (n_q,) (Pinocchio order) with zero joint velocities, keep the
        object where it is, and recompute kinematics and contacts (``mj_forward``); for static
        tests and for placing the hand, not for control."""
        q = _vector(q, self.hand.nq, "q")
        s = self.scene
        self.data.qpos[s.qpos_index] = q
        self.data.qvel[s.qvel_index] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def link_poses(self, q: FloatArray) -> FloatArray:
        """(L, 4, 4) world poses of the bodies of ``hand.link_names`` with the joints at ``q``
        (:meth:`set_kinematic_hand`), to compare the simulated hand with the kinematic model."""
        self.set_kinematic_hand(q)
        bodies = self.scene.link_body
        out = np.tile(np.eye(4), (bodies.size, 1, 1))
        out[:, :3, :3] = self.data.xmat[bodies].reshape(-1, 3, 3)
        out[:, :3, 3] = self.data.xpos[bodies]
        return out

    def set_base_pose(self, wMb: FloatArray) -> None:
        """Move a mocap hand base (``base="mocap"``) to ``wMb`` (4, 4), or the target a
        floating base is welded to (``base="floating"``); it takes effect at the next step."""
        if self.scene.options.base == "fixed":
            raise ConfigError(
                "MujocoBackend.set_base_pose needs base='mocap' or 'floating'; this hand is "
                "welded at hand.wMb"
            )
        wMb = check_pose(wMb, "wMb")
        body = self.scene.base_body
        if self._wrist_q >= 0:
            body = self.model.body(WRIST_TARGET).id
        mocap = int(self.model.body_mocapid[body])
        self.data.mocap_pos[mocap] = wMb[:3, 3]
        self.data.mocap_quat[mocap] = mujoco_quat(wMb)

    def set_table_contact(self, enabled: bool) -> None:
        """Let the table touch the hand and the object (``enabled``) or nothing: an object
        taken off its support at once, where it is (the grasp generator checks that a table-top
        grasp holds the object without the table). A scene without a table raises
        ConfigError."""
        if self.scene.options.table is None:
            raise ConfigError("MujocoBackend.set_table_contact: this scene has no table")
        geom = self.model.geom(TABLE_GEOM).id
        contype, conaffinity = (TABLE_BIT, HAND_BIT | OBJECT_BIT) if enabled else (0, 0)
        self.model.geom_contype[geom], self.model.geom_conaffinity[geom] = contype, conaffinity

    def object_pose_in_model(self) -> FloatArray:
        """(4, 4) object pose the model was compiled with (its ``qpos0``)."""
        a = self.scene.object_qpos
        qpos0 = self.model.qpos0
        return pose_from_mujoco(qpos0[a : a + 3], qpos0[a + 3 : a + 7])

    def object_velocity(self) -> tuple[FloatArray, FloatArray]:
        """Linear velocity of the object frame origin [m/s] and angular velocity [rad/s], both
        in world axes."""
        return self._forces.object_velocity()

    def applied_torques(self) -> FloatArray:
        """(n_v,) torques the motors exert [N*m] after clipping, Pinocchio order."""
        s = self.scene
        tau = np.zeros(self.hand.nv)
        act = s.ctrl_index >= 0
        tau[act] = self.data.actuator_force[s.ctrl_index[act]]
        return tau

    def ground_truth_contacts(self) -> SimContacts:
        """Hand-object contacts and forces as MuJoCo computes them at the current state.

        Positions on the hand surface, normals out of the object, forces exerted on the object
        (world frame, [N]; into the object), link indices into ``hand.link_names``. For baselines
        and comparisons only: the controller never sees them.

        Runs ``mj_forward`` first (about the cost of one step) so that contacts and forces belong
        to the current positions, not to those before the last integration step; this does not
        change the simulated trajectory.
        """
        mujoco.mj_forward(self.model, self.data)
        return hand_object_contacts(self.scene, self.data)

    def warnings(self) -> dict[str, int]:
        """MuJoCo warning counts since the last reset, and the steps whose failed contact solve
        was taken again (``step_retries``, ``step_retries_failed``; see
        :mod:`wholehand_plugins.mujoco.step_guard`). All zero in a healthy simulation."""
        return {
            **warning_counts(self.data),
            "step_retries": self._guard.retries,
            "step_retries_failed": self._guard.failed_retries,
        }

    def _check_warnings(self) -> None:
        # Counts only grow between resets: the names are looked at only when one has changed.
        total = int(self.data.warning.number.sum()) + self._guard.retries
        if total == self._warnings_seen:
            return
        self._warnings_seen = total
        for name, count in self.warnings().items():
            if count and name not in self._warned:
                self._warned.add(name)
                log.warning(
                    "MuJoCo warning %r at t = %.4f s (%d so far) for hand %s with object %s: %s",
                    name,
                    self.time,
                    count,
                    self.hand.name,
                    self.obj.name,
                    _WARNING_MEANING.get(name, "see MuJoCo's mjtWarning"),
                )
