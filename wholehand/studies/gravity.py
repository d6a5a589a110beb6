"""Gravity study (an open question of the paper): the perturbation protocol with gravity on.

The paper runs its studies without gravity and allocates quasi-statically, balancing no external
wrench. Here gravity is on. The grasp settles with the object held at its initial pose by springs
(``supported_settle``: a grasp made on a supported object); when the settle ends the support goes
and the object's weight adds to every load of the protocol. Two variants of the paper's method meet
the same trials: ``qp`` as in the paper, and ``qp+weight``, whose allocator balances the object's
known weight (``G f + m g = 0``, :class:`~wholehand.loop.regulation.ForceRegulation` ``weight``).
Does the quasi-static squeeze hold the weight, and does compensating it help? Grasps, angles and
pull axes are those of the perturbation study (same seeds), so its gravity-free rows are the third
column of the comparison.
"""

from __future__ import annotations

from dataclasses import dataclass

from wholehand.grasps.store import stored_grasp_indices
from wholehand.loop.trial import TrialSpec
from wholehand.models.object_catalogue import PAPER_OBJECTS
from wholehand.studies.base import DEFAULT_HAND, TrialJob, derive_seed, protocol_for
from wholehand.studies.perturbation import PerturbationStudy

METHODS = {"qp": False, "qp+weight": True}
"""Method label -> whether force regulation balances the object's weight."""


@dataclass(frozen=True)
class GravityConfig:
    """Design of one size of the gravity study."""

    objects: tuple[str, ...]
    grasps: tuple[int, ...]
    thetas: tuple[float, ...]
    repeats: int
    """Random axes per grasp at each theta > 0 (theta = 0 runs once)."""
    methods: tuple[str, ...] = tuple(METHODS)


CONFIGS = {
    "full": GravityConfig(PAPER_OBJECTS, tuple(range(10)), (0.0, 30.0, 60.0, 90.0), 5),
    "quick": GravityConfig(("077_rubiks_cube", "065-f_cups"), (0, 1), (0.0, 60.0), 1),
    "tiny": GravityConfig(("077_rubiks_cube",), (0,), (0.0,), 1),
}


class GravityStudy(PerturbationStudy):
    name = "gravity"
    description = (
        "the perturbation protocol with gravity on: qp as in the paper vs qp balancing the "
        "object's known weight (qp+weight)"
    )

    def jobs(self, size: str, seed: int, hand: str = DEFAULT_HAND) -> list[TrialJob]:
        cfg = CONFIGS[self.check_size(size)]
        # The grasp closes on the object held in place; its weight comes when the settle ends.
        protocol = {**protocol_for(size), "supported_settle": True}
        jobs: list[TrialJob] = []
        for oi, obj in enumerate(cfg.objects):
            for grasp in stored_grasp_indices(hand, obj, "power", cfg.grasps):
                for theta in cfg.thetas:
                    for repeat in range(1 if theta == 0.0 else cfg.repeats):
                        # The perturbation study's seed for these keys: the same pull axes.
                        trial_seed = derive_seed(seed, oi, grasp, repeat)
                        for method in cfg.methods:
                            spec = TrialSpec(
                                hand=hand,
                                object=obj,
                                grasp=grasp,
                                allocator="qp",
                                theta_deg=theta,
                                seed=trial_seed,
                                gravity=True,
                                balance_weight=METHODS[method],
                                protocol_params=protocol,
                            )
                            labels = {"method": method, "repeat": repeat}
                            jobs.append(TrialJob(len(jobs), spec, labels))
        return jobs
