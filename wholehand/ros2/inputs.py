"""Joint names mapped onto the hand model, and incoming messages checked, or rejected with a
reason.

A joint state is accepted only when it names every joint the model needs (in any order, after
``[joints] rename``), names nothing else (except ``[joints] ignore``), has positions (and
velocities and efforts, when sent) of the names' length, all finite, positions within the joint
limits (plus :data:`LIMIT_SLACK`), and a stamp that is finite and not ahead of this clock. A
pose is accepted when it is in the configured frame, finite, has a unit-normalisable quaternion
and a stamp as above. Anything else raises :class:`RejectedMessage` with a short reason; the backend
counts reasons and keeps the last good sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.errors import ConfigError, WholehandError
from wholehand.loop.control_loop import BROKEN_READING
from wholehand.models.hand import HandModel
from wholehand.ros2.config import HardwareConfig
from wholehand.ros2.messages import JointStateMsg, PoseMsg

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

LIMIT_SLACK = BROKEN_READING
"""How far past a joint limit a measured position is still believed [rad]: the loop's own bound
for a broken reading (:data:`~wholehand.loop.control_loop.BROKEN_READING`). Encoders and
calibration put real joints a little past their URDF limits, and a finger pressed on an object
goes past them too (0.2 rad in the robot double's reach episodes); rejecting the whole joint
state for it would leave every joint without a fresh reading. The gate of ``wholehand control``
still refuses a joint past its limit by more than its ``joint_margin`` until it persists."""


class RejectedMessage(WholehandError):  # noqa: N818 - a verdict, not a failure
    """An incoming message that cannot be used; ``reason`` is a short key for counting."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass(frozen=True)
class JointSample:
    """One accepted joint state in model order."""

    stamp: float
    """Measurement time [s] (the header stamp)."""
    q: FloatArray
    """(n_q,) positions [rad], followers of coupled joints set from their leaders if not sent."""
    dq: FloatArray | None
    """(n_v,) velocities [rad/s]; None when the message had none."""
    effort: FloatArray | None
    """(n_v,) measured efforts [N*m] (0 for joints not sent); None when the message had none."""


class JointStateReader:
    """Maps ``sensor_msgs/msg/JointState`` onto the hand model's joint order.

    Args:
        hand: the hand (its moving joints; followers of coupled joints may be left out).
        config: the renames and ignored names.
    """

    def __init__(self, hand: HandModel, config: HardwareConfig) -> None:
        model = hand.model
        unknown = sorted(set(config.rename) - set(hand.joint_names))
        if unknown:
            raise ConfigError(
                f"{config.path or 'hardware config'}: [joints] rename names {unknown}, which are "
                f"not joints of hand {hand.name!r}; its joints: {hand.joint_names}"
            )
        self.hand = hand
        self.msg_name = {j: config.rename.get(j, j) for j in hand.joint_names}
        """Model joint -> its name in messages."""
        self._q_index = {
            self.msg_name[j]: model.joints[model.getJointId(j)].idx_q for j in hand.joint_names
        }
        self.required = frozenset(
            self.msg_name[j] for j in hand.joint_names if j not in hand.mimics
        )
        self.ignored = frozenset(config.ignore)
        self.config_path = str(config.path) if config.path else None
        """The hardware config the renames come from, for the messages."""
        self.max_future = config.safety.max_future_stamp
        self._name_at_q = {self._q_index[self.msg_name[j]]: j for j in hand.joint_names}
        self._cache: tuple[tuple[str, ...], npt.NDArray[np.intp], npt.NDArray[np.intp]] | None
        self._cache = None
        self._q_neutral = hand.neutral()
        """Positions of joints a message may leave out (followers, set from their leaders)."""
        self._lower = hand.q_lower - LIMIT_SLACK
        self._upper = hand.q_upper + LIMIT_SLACK

    def _mapping(self, names: tuple[str, ...]) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
        """Message rows of the model's joints and their q indices (cached per name order)."""
        if self._cache is not None and self._cache[0] == names:
            return self._cache[1], self._cache[2]
        if len(set(names)) != len(names):
            raise RejectedMessage("duplicate_names", f"joint names repeat: {list(names)}")
        strange = sorted(set(names) - set(self._q_index) - self.ignored)
        if strange:
            raise RejectedMessage("unknown_joint", self._unknown_names(strange))
        missing = sorted(self.required - set(names))
        if missing:
            raise RejectedMessage("missing_joint", f"joint state lacks joints {missing}")
        rows = np.array([i for i, n in enumerate(names) if n in self._q_index], dtype=np.intp)
        idx = np.array([self._q_index[names[i]] for i in rows], dtype=np.intp)
        self._cache = (names, rows, idx)
        return rows, idx

    def _unknown_names(self, strange: list[str]) -> str:
        """Why the message's names ``strange`` are not read, and the fix."""
        renamed = {n: self.msg_name[n] for n in strange if self.msg_name.get(n, n) != n}
        where = self.config_path or "the hardware config"
        if renamed:
            expected = ", ".join(f"{n!r} as {m!r}" for n, m in renamed.items())
            return (
                f"joint names {strange} are joints of hand {self.hand.name!r}, but {where} "
                f"[joints] rename expects {expected}: remove those renames if the robot "
                "publishes the URDF's names"
            )
        return (
            f"joint names {strange} are not joints of hand {self.hand.name!r} (expected: "
            f"{sorted(self._q_index)}); rename them in {where} [joints] rename (URDF name = "
            "robot name) or list them in [joints] ignore"
        )

    def read(self, msg: JointStateMsg, now: float) -> JointSample:
        """The sample of ``msg``, checked.

        Args:
            now: this process's clock in the stamps' time base [s] (wall clock).

        Raises:
            RejectedMessage: why the message cannot be used.
        """
        _check_lengths(msg)
        check_stamp(msg.stamp, now, self.max_future)
        rows, idx = self._mapping(msg.names)
        hand = self.hand
        q = self._q_neutral.copy()
        q[idx] = msg.position[rows]
        if hand.coupled and len(rows) < hand.nq:
            q = hand.couple(q)
        if not np.isfinite(q).all():
            raise RejectedMessage(
                "not_finite", f"positions hold NaN or inf: {msg.position.tolist()}"
            )
        out = (q < self._lower) | (q > self._upper)
        if out.any():
            j = int(np.flatnonzero(out)[0])
            name = self._name_at_q[j]
            raise RejectedMessage(
                "out_of_range",
                f"joint {name!r} at {q[j]:.4g} rad is outside its limits "
                f"[{hand.q_lower[j]:.4g}, {hand.q_upper[j]:.4g}]",
            )
        dq = self._per_joint(msg.velocity, rows, idx, "velocities")
        effort = self._per_joint(msg.effort, rows, idx, "efforts")
        return JointSample(msg.stamp, q, dq, effort)

    def _per_joint(
        self, values: FloatArray, rows: IntArray, idx: IntArray, what: str
    ) -> FloatArray | None:
        """(n_v,) the message's ``values`` (velocities or efforts) in the model's order, zero
        for joints it does not name; None if it sends none."""
        if not values.size:
            return None
        out = np.zeros(self.hand.nv)
        out[idx] = values[rows]
        if not np.isfinite(out).all():
            raise RejectedMessage("not_finite", f"{what} hold NaN or inf")
        return out


def _check_lengths(msg: JointStateMsg) -> None:
    """Raise :class:`RejectedMessage` unless there is one position per name, and one velocity
    and one effort per name or none."""
    n = len(msg.names)
    if msg.position.shape != (n,):
        raise RejectedMessage("wrong_length", f"{msg.position.shape[0]} positions for {n} names")
    for what, arr in (("velocities", msg.velocity), ("efforts", msg.effort)):
        if arr.shape not in ((0,), (n,)):
            raise RejectedMessage("wrong_length", f"{arr.shape[0]} {what} for {n} names")


def check_stamp(stamp: float, now: float, max_future: float = 0.01) -> None:
    """Raise :class:`RejectedMessage` for a stamp that is not finite, not positive, or more than
    ``max_future`` [s] ahead of ``now``."""
    if not (math.isfinite(stamp) and stamp > 0.0):
        raise RejectedMessage("bad_stamp", f"stamp {stamp!r} s is not a positive time")
    if stamp > now + max_future:
        raise RejectedMessage(
            "future_stamp",
            f"stamp is {stamp - now:.3f} s ahead of this clock; synchronise the clocks (chrony)",
        )


def read_pose(msg: PoseMsg, frame_id: str, now: float, max_future: float = 0.01) -> FloatArray:
    """The (4, 4) pose of ``msg``, checked (``now``, ``max_future``: see :func:`check_stamp`).

    Raises:
        RejectedMessage: wrong frame, NaN or inf, a quaternion far from unit length, a bad stamp.
    """
    if msg.frame_id != frame_id:
        raise RejectedMessage(
            "wrong_frame", f"pose in frame {msg.frame_id!r}, the controller needs {frame_id!r}"
        )
    if not (np.isfinite(msg.position).all() and np.isfinite(msg.quat_xyzw).all()):
        raise RejectedMessage("not_finite", "pose holds NaN or inf")
    norm = float(np.linalg.norm(msg.quat_xyzw))
    if abs(norm - 1.0) > 1e-3:
        raise RejectedMessage(
            "bad_quaternion", f"orientation quaternion has norm {norm:.6g}, not 1"
        )
    check_stamp(msg.stamp, now, max_future)
    x, y, z, w = msg.quat_xyzw / norm
    M = np.eye(4)
    M[:3, :3] = pin.Quaternion(w, x, y, z).toRotationMatrix()
    M[:3, 3] = msg.position
    return M


def model_joint_name(hand: HandModel, config: HardwareConfig, name: str) -> str:
    """The model joint named ``name`` by the model or by the robot (after ``[joints] rename``);
    ``name`` itself when neither knows it."""
    if name in hand.joint_names:
        return name
    robot = {v: k for k, v in config.rename.items()}
    return robot.get(name, name)


def _ordered_dofs(
    hand: HandModel, config: HardwareConfig, names: tuple[str, ...], expected: list[str], what: str
) -> npt.NDArray[np.intp]:
    """Velocity indices of ``names`` (model or robot names) in their order, checked to name
    every joint of ``expected`` exactly once and nothing else."""
    where = config.path or "hardware config"
    model_names = [model_joint_name(hand, config, n) for n in names]
    strange = [n for n, m in zip(names, model_names, strict=True) if m not in expected]
    if strange:
        raise ConfigError(
            f"{where}: {what} names {strange}, which are not among the joints it commands on "
            f"hand {hand.name!r}: {expected}"
        )
    repeated = sorted({m for m in model_names if model_names.count(m) > 1})
    if repeated:
        raise ConfigError(f"{where}: {what} names the joints {repeated} more than once")
    missing = [j for j in expected if j not in model_names]
    if missing:
        raise ConfigError(
            f"{where}: {what} leaves out {missing}; it must list every one of {expected} once, "
            "in the order of the robot controller's `joints` parameter"
        )
    model = hand.model
    return np.array([model.joints[model.getJointId(m)].idx_v for m in model_names], dtype=np.intp)


def command_dofs(hand: HandModel, config: HardwareConfig) -> npt.NDArray[np.intp]:
    """(m,) velocity indices of the torque command's joints in its order (``[joints]
    command``): every actuated joint of the hand (not of an arm) exactly once.

    Raises:
        ConfigError: no ``[joints] command``, or one that names a joint that is not an actuated
            hand joint, names one twice, or leaves one out.
    """
    if config.command_joints is None:
        raise ConfigError(
            f"{config.path or 'hardware config'}: [joints] command is missing: list the torque "
            "command's joints in the order of the hand controller's `joints` parameter"
        )
    hand_joints = np.flatnonzero(hand.actuated_dofs & ~hand.arm_dofs)
    expected = [hand.joint_names[i] for i in hand_joints]
    return _ordered_dofs(hand, config, config.command_joints, expected, "[joints] command")


def arm_command_dofs(hand: HandModel, config: HardwareConfig) -> npt.NDArray[np.intp]:
    """(m,) velocity indices of the arm command's joints in its order (``[arm] joints``): every
    arm joint of an assembly exactly once.

    Raises:
        ConfigError: the hand has no arm, or ``[arm] joints`` does not name every arm joint once.
    """
    where = config.path or "hardware config"
    arm = np.flatnonzero(hand.arm_dofs)
    if not arm.size:
        raise ConfigError(
            f"{where}: [topics] arm_command is set but {hand.name!r} has no arm; remove it or "
            "give an arm-hand assembly (--hand)"
        )
    expected = [hand.joint_names[i] for i in arm]
    return _ordered_dofs(hand, config, config.arm.joints, expected, "[arm] joints")
