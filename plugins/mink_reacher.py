"""Reacher ``mink``: a joint-velocity IK QP over a floating wrist or an arm, and the fingers.

Tasks: a frame task (position and orientation) for the palm and for every fingertip target; the
fingertip weights rise from ``tip_weight_far`` to 1 as the palm nears its target (from
``far`` to ``near`` metres away), the palm's stay fixed, so the hand first carries its open
fingers to the object and then shapes them; a posture task toward the target joint angles
(lightly on an arm's joints). Limits:

- joint positions (mink's ``ConfigurationLimit``);
- hand-table clearance for every hand surface sample near the table (:class:`TableLimit`);
- hand-object clearance for the hand surface samples nearest the object, from its SDF
  (:class:`ObjectClearanceLimit`), dropped when ``targets.avoid_object`` is False (the grasp
  stage);
- an arm's links: clearance from the table and the object, always, from MuJoCo geom distances
  (mink's ``CollisionAvoidanceLimit``) to the convex parts of the object's decomposition (a mesh
  geom's distance is to its convex hull, which would fill cavities);
- on request, finger-finger clearance (``self_collision``).

The QP's velocity is scaled down as a whole to the speed limits, which keeps every collision
bound that was not violated already.

A robot's measured state can violate a limit (a finger a little below the table's clearance)
while another one holds a joint at its range's end, so that no velocity meets them all: then
the step keeps each violated row's violation from growing instead of undoing it this period
(:class:`HeldViolations`, counted as ``relaxed`` in :attr:`MinkReacher.faults`), and if that
has no solution either, the hand stays where it is (``held``). The next step tries the full
limits again.

The IK runs on its own MuJoCo model (:func:`build_reach_model`), never the simulation's: the
hand on a free joint (a floating wrist) or the arm fixed at its mount, the object and the table
on mocap bodies.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import mink
import mujoco
import numpy as np
import numpy.typing as npt

from wholehand.backends.table import TABLE_GEOM, Table
from wholehand.errors import ConfigError
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel
from wholehand.reaching.base import Reacher, ReachTargets

from .mujoco.hand_spec import load_hand_spec, weld_locked_joints
from .mujoco.object_spec import add_object_geoms
from .mujoco.poses import mujoco_quat, pose_from_mujoco
from .mujoco.scene import add_table
from .mujoco.scene_options import SceneOptions
from .reach_limits import HeldViolations, ObjectClearanceLimit, TableLimit

FloatArray = npt.NDArray[np.float64]

WRIST_JOINT = "wrist_free"
"""Name of the free joint at the hand base in the IK model."""
OBJECT_MOCAP = "object"
"""Name of the object's mocap body in the IK model."""

ARM_POSTURE_COST = 0.01
"""Posture cost of an assembly's arm joints [1/rad]: a light pull toward the target posture's
arm angles (the stage passes the current ones), to settle the arm's redundancy."""

SELF_CLEARANCE = 0.002
"""Least distance between two fingers with ``self_collision`` on [m]."""

_HAND, _OBJECT, _TABLE = 1, 2, 4  # contype bits (mink's pair filter reads them)


def build_reach_model(
    hand: HandModel, obj: ObjectModel, table: Table | None
) -> tuple[mujoco.MjModel, list[str], list[str], list[str]]:
    """The IK model and the names of its hand, object and arm collision geoms.

    A hand alone gets a free joint at its base (a floating wrist); an assembly's arm root is
    fixed at the mount pose. The object is a mocap body; the table sits on a mocap body of its
    own, since mink drops the pairs of a geom of the world body (or of any body welded to it)
    with a body hanging from the world (the arm's first link, a floating hand's root).
    """
    spec = load_hand_spec(hand)
    spec.modelname = f"reach_{hand.name}"
    weld_locked_joints(spec, hand)
    root = list(spec.worldbody.bodies)[0]
    if hand.arm_dofs.any():
        root.pos = np.asarray(hand.wMb)[:3, 3].tolist()
        root.quat = mujoco_quat(np.asarray(hand.wMb)).tolist()
    else:
        root.add_freejoint(name=WRIST_JOINT)
    links = set(hand.link_names)
    hand_geoms: list[str] = []
    arm_geoms: list[str] = []
    for body in spec.bodies:
        for k, geom in enumerate(body.geoms):
            geom.name = geom.name or f"{body.name}/collision_{k}"
            geom.contype, geom.conaffinity = _HAND, _HAND | _OBJECT | _TABLE
            (hand_geoms if body.name in links else arm_geoms).append(geom.name)
    obj_body = spec.worldbody.add_body(name=OBJECT_MOCAP, mocap=True)
    add_object_geoms(spec, obj_body, obj, SceneOptions(), float(obj.friction))
    object_geoms = [g.name for g in obj_body.geoms]
    for geom in obj_body.geoms:
        geom.contype, geom.conaffinity = _OBJECT, _HAND
    if table is not None:
        add_table(spec.worldbody.add_body(name="table", mocap=True), table, _TABLE, _HAND)
    return spec.compile(), hand_geoms, object_geoms, arm_geoms


def finger_pairs(hand: HandModel, model: mujoco.MjModel) -> list[tuple[list[str], list[str]]]:
    """(geoms of finger i, geoms of finger j) for every pair of fingers of ``hand.config``."""
    geoms = {}
    for finger, links in hand.config.fingers.items():
        bodies = {model.body(link).id for link in links if link in hand.link_names}
        names = [model.geom(g).name for g in range(model.ngeom) if model.geom_bodyid[g] in bodies]
        if names:
            geoms[finger] = names
    fingers = sorted(geoms)
    return [(geoms[a], geoms[b]) for i, a in enumerate(fingers) for b in fingers[i + 1 :]]


class MinkReacher(Reacher):
    """Fingertip-plus-palm IK with collision limits (see the module docstring).

    Args:
        hand, obj, table: the hand, the object and the table (None: no table).
        palm_cost: position [1/m] and orientation [1/rad] cost of the palm task.
        tip_cost: position cost of each fingertip task at full weight [1/m] (orientation:
            ``tip_orientation_cost``).
        tip_orientation_cost: orientation cost of each fingertip task at full weight [1/rad].
        tip_weight_far: fingertip weight (fraction of full) while the palm is ``far`` away.
        near, far: palm-to-target distances [m] between which the fingertip weight rises.
        posture_cost: cost of the posture task [1/rad].
        gain: task gain (fraction of the error corrected per period).
        max_speed: speed limits: wrist [m/s], wrist rotation [rad/s] (an assembly: every arm
            joint [rad/s]), finger joints [rad/s].
        clearance: least hand-table and hand-object distance [m] (mink's
            ``minimum_distance_from_collisions``).
        detection: distance below which a hand sample (and an arm link's geom pair) is
            constrained [m]. Within one 5 ms cycle the speed limits move a point a few mm at most
            (about 6 mm for a hand at the end of a 0.8 m arm turning at 1.5 rad/s), so 2 cm
            leaves a margin; 4 cm constrained more pairs and made the reacher's tail longer.
        solver: a qpsolvers solver name.
        damping: Levenberg-Marquardt damping of the IK QP.
        self_collision: keep the fingers ``SELF_CLEARANCE`` apart (each pair of fingers' links;
            off by default, as in the measured studies).
    """

    def __init__(
        self,
        hand: HandModel,
        obj: ObjectModel,
        table: Table | None = None,
        palm_cost: tuple[float, float] = (1.0, 0.5),
        tip_cost: float = 1.0,
        tip_orientation_cost: float = 0.02,
        tip_weight_far: float = 0.05,
        near: float = 0.03,
        far: float = 0.15,
        posture_cost: float = 0.05,
        gain: float = 1.0,
        max_speed: tuple[float, float, float] = (0.3, 1.5, 3.0),
        clearance: float = 0.005,
        detection: float = 0.02,
        solver: str = "daqp",
        damping: float = 1e-3,
        self_collision: bool = False,
    ) -> None:
        if not 0.0 <= near < far:
            raise ConfigError(f"MinkReacher: need 0 <= near < far [m], got {near}, {far}")
        if not 0.0 <= tip_weight_far <= 1.0:
            raise ConfigError(
                f"MinkReacher: tip_weight_far must be in [0, 1], got {tip_weight_far}"
            )
        if min(max_speed) <= 0.0:
            raise ConfigError(f"MinkReacher: max_speed must be > 0, got {max_speed}")
        self.hand, self.obj, self.table = hand, obj, table
        self.faults: Counter[str] = Counter()
        """Steps taken with the limits' violations held (``relaxed``) or not taken (``held``)."""
        self.model, _, object_geoms, arm_geoms = build_reach_model(hand, obj, table)
        self.configuration = mink.Configuration(self.model)
        self._kin = HandKinematics(hand)
        self._kin_fresh = False
        self._wMo = np.eye(4)
        m = self.model
        self.floating = not hand.arm_dofs.any()
        self._wrist_q = self._wrist_v = -1
        if self.floating:
            joint = m.joint(WRIST_JOINT)
            self._wrist_q, self._wrist_v = int(joint.qposadr[0]), int(joint.dofadr[0])
        self._qpos = np.array([m.joint(n).qposadr[0] for n in hand.joint_names], dtype=np.intp)
        self._dof = np.array([m.joint(n).dofadr[0] for n in hand.joint_names], dtype=np.intp)
        self._mocap = int(m.body_mocapid[m.body(OBJECT_MOCAP).id])
        self.palm_cost = palm_cost
        self.tip_cost, self.tip_orientation_cost = float(tip_cost), float(tip_orientation_cost)
        self.tip_weight_far, self.near, self.far = float(tip_weight_far), near, far
        self.gain, self.max_speed = float(gain), tuple(float(s) for s in max_speed)
        self.solver, self.damping = solver, float(damping)
        self._tasks: dict[str, mink.FrameTask] = {}
        posture_weights = np.zeros(m.nv)
        posture_weights[self._dof] = posture_cost
        self._arm = self._dof[hand.arm_dofs]  # IK dofs of an assembly's arm joints
        self._finger_dof = self._dof[~hand.arm_dofs]
        posture_weights[self._arm] = ARM_POSTURE_COST
        self.posture = mink.PostureTask(m, cost=posture_weights, gain=self.gain)
        self.limits: list[Any] = [mink.ConfigurationLimit(m)]
        collide: dict[str, Any] = {"gain": 0.85, "minimum_distance_from_collisions": clearance}
        collide["collision_detection_distance"] = detection
        if table is not None:
            self.limits.append(TableLimit(self, table, 0.85, clearance, detection))
            if arm_geoms:
                pairs = [(arm_geoms, [TABLE_GEOM])]
                self.limits.append(mink.CollisionAvoidanceLimit(m, pairs, **collide))
        if self_collision:
            pairs = finger_pairs(hand, m)
            self.limits.append(
                mink.CollisionAvoidanceLimit(
                    m,
                    pairs,
                    gain=0.85,
                    minimum_distance_from_collisions=SELF_CLEARANCE,
                    collision_detection_distance=detection,
                )
            )
        self.object_limit = ObjectClearanceLimit(self, obj, 0.85, clearance, detection)
        # The arm's links keep clear of the object too, even at the grasp stage.
        if arm_geoms:
            arm_pairs = [(arm_geoms, object_geoms)]
            self.limits.append(mink.CollisionAvoidanceLimit(m, arm_pairs, **collide))

    def _task(self, link: str) -> mink.FrameTask:
        if link not in self._tasks:
            self._tasks[link] = mink.FrameTask(link, "body", 1.0, 1.0, gain=self.gain)
        return self._tasks[link]

    def hand_state(self) -> tuple[FloatArray, FloatArray]:
        """The IK model's current joint angles (n_q,) and base pose (4, 4)."""
        qpos = self.configuration.data.qpos
        w = self._wrist_q
        if not self.floating:
            return qpos[self._qpos].copy(), np.asarray(self.hand.wMb, dtype=float).copy()
        return qpos[self._qpos].copy(), pose_from_mujoco(qpos[w : w + 3], qpos[w + 3 : w + 7])

    def _set_state(self, q: FloatArray, wMb: FloatArray, wMo: FloatArray) -> None:
        data = self.configuration.data
        if self.floating:
            data.qpos[self._wrist_q : self._wrist_q + 3] = wMb[:3, 3]
            data.qpos[self._wrist_q + 3 : self._wrist_q + 7] = mujoco_quat(wMb)
        data.qpos[self._qpos] = q
        data.mocap_pos[self._mocap] = wMo[:3, 3]
        data.mocap_quat[self._mocap] = mujoco_quat(wMo)
        self._wMo = np.array(wMo, dtype=float)
        self.configuration.update()
        self._kin_fresh = False

    def hand_kinematics(self) -> HandKinematics:
        """The hand's kinematics at the IK model's current joint angles and base pose (one
        forward pass per step, shared by the limits)."""
        if not self._kin_fresh:
            self._kin.update(*self.hand_state())
            self._kin_fresh = True
        return self._kin

    def object_pose(self) -> FloatArray:
        """(4, 4) the object's pose in the IK model [m]."""
        return self._wMo

    def tip_weight(self, palm_distance: float) -> float:
        """Fingertip task weight (fraction of full) at a palm-to-target distance [m]."""
        rise = (self.far - palm_distance) / (self.far - self.near)
        return float(np.clip(rise, 0.0, 1.0) * (1.0 - self.tip_weight_far) + self.tip_weight_far)

    def step(
        self, q: FloatArray, wMb: FloatArray, wMo: FloatArray, targets: ReachTargets, dt: float
    ) -> tuple[FloatArray, FloatArray]:
        self._set_state(np.asarray(q, dtype=float), wMb, wMo)
        palm_target = targets.links[targets.palm]
        palm_now = self.configuration.get_transform_frame_to_world(targets.palm, "body")
        palm_distance = float(np.linalg.norm(palm_now.translation() - palm_target[:3, 3]))
        weight = self.tip_weight(palm_distance)
        tasks: list[Any] = []
        for link, target in targets.links.items():
            task = self._task(link)
            if link == targets.palm:
                task.set_position_cost(self.palm_cost[0])
                task.set_orientation_cost(self.palm_cost[1])
            else:
                task.set_position_cost(weight * self.tip_cost)
                task.set_orientation_cost(weight * self.tip_orientation_cost)
            task.set_target(mink.SE3.from_matrix(np.asarray(target, dtype=float)))
            tasks.append(task)
        posture = self.configuration.q.copy()
        posture[self._qpos] = targets.q
        self.posture.set_target(posture)
        tasks.append(self.posture)
        limits = self.limits + ([self.object_limit] if targets.avoid_object else [])
        velocity = self._solve(tasks, dt, limits)
        velocity *= self._speed_scale(velocity)
        self.configuration.integrate_inplace(velocity, dt)
        self._kin_fresh = False
        return self.hand_state()

    def fault_counts(self) -> dict[str, int]:
        return dict(self.faults)

    def _solve(self, tasks: list[Any], dt: float, limits: list[Any]) -> FloatArray:
        """The IK velocity under ``limits``; where they have no common solution, under the
        limits with their violations held (module docstring; counted in :attr:`faults`)."""
        try:
            return np.asarray(
                mink.solve_ik(
                    self.configuration, tasks, dt, self.solver, damping=self.damping, limits=limits
                )
            )
        except mink.NoSolutionFound:
            pass
        held = [HeldViolations(limit) for limit in limits]
        try:
            velocity = mink.solve_ik(
                self.configuration, tasks, dt, self.solver, damping=self.damping, limits=held
            )
        except mink.NoSolutionFound:
            self.faults["held"] += 1
            return np.zeros(self.configuration.model.nv)
        self.faults["relaxed"] += 1
        return np.asarray(velocity)

    def _speed_scale(self, velocity: FloatArray) -> float:
        """Largest factor <= 1 that keeps the wrist (or arm joint) and finger speeds within
        ``max_speed``."""
        v = self._wrist_v
        if self.floating:
            linear = float(np.linalg.norm(velocity[v : v + 3]))
            angular = float(np.linalg.norm(velocity[v + 3 : v + 6]))
        else:  # an arm: no wrist twist; its joints share the wrist's rotational limit
            linear = 0.0
            angular = float(np.max(np.abs(velocity[self._arm]), initial=0.0))
        joints = float(np.max(np.abs(velocity[self._finger_dof]), initial=0.0))
        speeds = (linear, angular, joints)
        ratios = [s / max(x, 1e-12) for s, x in zip(self.max_speed, speeds, strict=True)]
        return min(1.0, *ratios)
