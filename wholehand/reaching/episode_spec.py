"""The parameters of a reach-grasp-hold-regrasp episode (:mod:`wholehand.reaching.episode`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class EpisodeSpec:
    """Everything that defines an episode; equal specs give equal episodes."""

    hand: str = "allegro_right"
    object: str = "077_rubiks_cube"
    seed: int = 0
    rate: float = 200.0
    """Control rate [Hz] (simulated time)."""
    duration: float = 14.0
    """Longest episode [s]."""
    reacher: str = "mink"
    estimator: str = "mesh_sdf"
    allocator: str = "qp"
    start: str = "held"
    """Where the object starts: ``held`` out by the person, or resting on the ``table`` (needs
    the hand's table-top grasps, ``wholehand grasps generate --on-table``)."""
    hold_height: float = 0.25
    """Height of the object's frame above the table top where the person holds it [m]."""
    displace: float = 0.04
    """How far the person moves the object while the hand reaches [m]."""
    displace_at: float = 0.5
    """When [s]."""
    release_after: float = 0.5
    """Holding time before the person lets go [s]."""
    push: float = 1.0
    """Push while held, in the object's weights [-]: a push of ``push * m * g`` [N], horizontal,
    so that every object is pushed alike per unit of mass."""
    twist: float = 1.0
    """Twist while held, in the object's weights at its rim [-]: ``twist * m * g * r`` [N*m]
    with r half the object's largest side, about a random axis (a push of the same size
    applied at the rim, tangentially)."""
    pulse: float = 0.3
    """Duration of the push and the twist [s]."""
    snatch: float = 0.15
    """How far the snatch pulls the object [m]."""
    hold_after: float = 1.0
    """Holding time after the regrasp that ends the episode [s]."""
    balance_weight: bool = True
    """Force regulation balances the object's known weight (``ForceRegulation(weight=...)``);
    False: the paper's quasi-static balance of no external wrench. Not applied with
    ``start="table"``, where the table carries the weight."""
    self_collision: bool = False
    """The reacher keeps the fingers apart (the ``mink`` reacher's ``self_collision``)."""
    gravity_compensation: bool = True
    """The hand's actuators hold their own links against gravity, while reaching and while
    regulating (``ForceRegulation(gravity_compensation=True)``); False: the paper's ``tau = J^T
    f``, the fingers' weight left to the grip."""
    tracker_rate: float = 0.0
    """The object pose as a tracker gives it: frames at this rate [Hz] with
    :attr:`tracker_latency`, as on a robot (0: the exact pose every cycle, the default)."""
    tracker_latency: float = 0.0
    """The tracker's latency [s] (with :attr:`tracker_rate`)."""
    tracker_predict: float = 0.0
    """With a tracker: the controller carries each pose forward to the joint state's time at
    the object's velocity, at most this long [s]
    (:class:`~wholehand.loop.filters.PosePredictor`; 0: no prediction, the default)."""
    qp_deadline: float = 0.0
    """The QP allocator's deadline [s] of wall time, as the robot's controller runs it (0: none,
    the default); a deadline makes the episode depend on the computer's speed."""
    hand_servo: str = "step"
    """Where the fingers' position targets (while reaching) are servoed: ``"step"``, by the
    simulated drives at every 1 ms step (the default); ``"command"``, by the controller at the
    control rate on the state when the command goes out, as the robot controller does for a
    hand without a position interface (``MujocoBackend(hand_servo=)``)."""
    person_sees: str = "stage"
    """How the person judges that the hand holds the object before letting go: ``"stage"``, the
    controller regulates (the default, and the robot double's person on the controller's
    status topic); ``"contacts"``, the thumb and two other fingers touch it
    (:class:`~wholehand.reaching.person.ContactHolds`), which can be while the hand still
    closes."""
