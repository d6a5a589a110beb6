"""Named defaults for every constant of the paper, in one place.

Section numbers refer to the paper "Real-Time Force Regulation for Whole-Hand Dexterous
Grasping" (Sec. III: method, Sec. IV: experiments). Every value can be overridden per run
through the keyword arguments of the plug-in or command that uses it.
"""

from __future__ import annotations

# --- Contact estimation (Sec. III-B) -----------------------------------------------------------
UNIFORM_SAMPLES_PER_LINK: int = 2000
"""Points drawn uniformly on each link surface before farthest-point reduction."""

SAMPLE_DENSITY_PER_CM2: float = 2.0
"""Target density of the reduced link samples [points / cm^2]."""

D_THRESH: float = 0.01
"""Signed-distance threshold below which a hand point is a contact candidate [m]."""

K_PER_LINK: int = 5
"""Maximum number of contacts kept per link, closest to the surface first."""

CONTACT_HYSTERESIS: float = 0.001
"""How much closer to the surface [m] a hand sample must be than one a link kept last cycle to
take its place among the link's K contacts. Not in the paper, whose top-K is re-selected each
cycle: there a finger rolling by a fraction of the sample spacing swaps its points (up to
17 mm apart), which moves the consistency rows and loses the QP's warm start. 0 restores the
paper's selection."""

# --- Force allocation (Sec. III-C, IV) ----------------------------------------------------------
MU: float = 0.7
"""Static friction coefficient of the linearised friction pyramid [-]."""

F_N_MIN: float = 10.0
"""Lower bound on the sum of contact normal forces [N]."""

TAU_MAX: float = 0.2
"""Joint torque limit of each actuated hand joint [N*m]."""

EPS_MARGIN: float = 0.5
"""Bound on the force components in Null(J_act^T) (actuation consistency) [N]."""

SVD_TOL: float = 1e-6
"""Singular-value tolerance that decides rank(J_act) [-]."""

BALANCE_TOL_FORCE: float = 1e-3
"""Largest residual force of an allocation that balances the object [N] (not in the paper: the
QP minimises the residual, and a held grasp's is below 1e-6 N)."""

BALANCE_TOL_TORQUE: float = 1e-4
"""Largest residual torque of an allocation that balances the object [N*m]."""

# --- Perturbation protocol (Sec. IV-A, Fig. 2) -------------------------------------------------
LOAD_FRACTION_OF_WEIGHT: float = 0.1
"""Load-test force as a fraction of the object weight m*g [-]."""

LOAD_DURATION: float = 1.0
"""Duration of the load along each of +x, -x, +y, -y, +z, -z [s]."""

GRAVITY: float = 9.81
"""Magnitude of gravity used to size the load test, even when simulation gravity is off [m/s^2]."""

# --- Reaching (Sec. III-D) ---------------------------------------------------------------------
PREGRASP_SWITCH_DISTANCE: float = 0.02
"""Mean fingertip error to the pre-grasp below which the target switches to the grasp [m]."""

PREGRASP_CLEARANCE: float = 0.03
"""Clearance a pre-grasp keeps from the object [m]."""

# --- Simulation --------------------------------------------------------------------------------
GRAVITY_VECTOR: tuple[float, float, float] = (0.0, 0.0, -9.81)
"""Gravity in the world frame when a scene enables it [m/s^2]; the paper's simulation studies
run without it (Sec. IV-A)."""
