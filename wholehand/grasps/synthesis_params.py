"""The weights and the schedule of grasp synthesis by optimisation
(:mod:`wholehand.grasps.synthesis`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from wholehand.backends.table import HAND_MARGIN


@dataclass(frozen=True)
class SynthesisParams:
    """Weights and schedule of the synthesis (defaults after DexGraspNet's, scaled to the
    project's samples)."""

    w_dis: float = 100.0
    """Weight of the contacts' distance to the surface [1/m]."""
    w_fc: float = 1.0
    """Weight of the force-closure term [-]."""
    w_align: float = 0.5
    """Weight of the pads' alignment with the object normal [-]."""
    w_pen: float = 300.0
    """Weight of the hand samples' depth inside the object [1/m]."""
    w_table: float = 300.0
    """Weight of the hand samples' depth below the table's margin [1/m]."""
    w_self: float = 300.0
    """Weight of the fingers' samples coming closer than ``self_gap`` [1/m]."""
    self_gap: float = 0.004
    """Least distance between samples of two fingers [m]."""
    iterations: int = 1500
    """Steps per start."""
    step_translation: float = 0.002
    """Largest base translation of one step [m], decayed with the temperature."""
    step_rotation: float = 0.02
    """Largest base rotation of one step [rad]."""
    step_joint: float = 0.02
    """Largest joint step [rad]."""
    switch_probability: float = 0.02
    """Chance per step that a contact point is re-drawn."""
    temperature: float = 1.0
    """Starting temperature of the Metropolis rule [energy units]."""
    cooling: float = 0.95
    """Temperature (and step) factor every ``cooling_every`` steps."""
    cooling_every: int = 30
    gap: tuple[float, float] = (0.01, 0.03)
    """Gap between the palm and the object's support at the start [m]."""
    joint_jitter: float = 0.15
    """Standard deviation of the start's joint angles around the pre-shape [rad]."""
    table_margin: float = HAND_MARGIN + 0.002
    """Least height of a hand sample above the table top [m]: a little above the margin the
    validation and the reacher keep (:data:`~wholehand.backends.table.HAND_MARGIN`)."""
    palm_contact: bool = True
    """A power grasp has a contact point on the palm face too."""
    envelop: Literal["coupled", "all", "none"] = "coupled"
    """Which fingers get a contact point on each of their phalanges (every link of the finger
    whose pads the closing moves) instead of one on the finger: ``coupled``, those whose
    phalanges one motor drives through a coupling (an underactuated finger holds an object
    with its whole length or not at all); ``all``; ``none``, one per finger (DexGraspNet's
    energy)."""
