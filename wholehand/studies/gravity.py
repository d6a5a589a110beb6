"""Gravity study (an open question of the paper): the perturbation protocol with gravity on.

The paper runs its studies without gravity and allocates quasi-statically, balancing no external
wrench. Here gravity is on. The grasp settles with the object held at its initial pose by springs
(``supported_settle``: a grasp made on a supported object); when the settle ends the support goes
and the object's weight adds to every load of the protocol. Three variants of the paper's method
meet the same trials: ``qp`` as in the paper; ``qp+weight``, whose allocator balances the
object's known weight (``G f + m g = 0``, :class:`~wholehand.loop.regulation.ForceRegulation`
``weight``); and ``qp+weight+fingers``, whose hand also holds its own links against gravity
(``tau = g(q) + J^T f``, ``gravity_compensation``). Does the quasi-static squeeze hold the
weight, and does compensating it help? Grasps, angles and pull axes are those of the
perturbation study (same seeds), so its gravity-free rows are the fourth column of the
comparison.
"""

from __future__ import annotations

from typing import Any

from wholehand.models.object_catalogue import PAPER_OBJECTS
from wholehand.studies.base import DEFAULT_HAND, TrialJob, protocol_for
from wholehand.studies.perturbation import PerturbationConfig, PerturbationStudy, pull_jobs

METHODS = {"qp": (False, False), "qp+weight": (True, False), "qp+weight+fingers": (True, True)}
"""Method label -> whether force regulation balances the object's weight, and whether the hand
also holds its own links against gravity (``TrialSpec.gravity_compensation``)."""


CONFIGS = {
    "full": PerturbationConfig(
        PAPER_OBJECTS, tuple(range(10)), (0.0, 30.0, 60.0, 90.0), 5, tuple(METHODS)
    ),
    "quick": PerturbationConfig(
        ("077_rubiks_cube", "065-f_cups"), (0, 1), (0.0, 60.0), 1, tuple(METHODS)
    ),
    "tiny": PerturbationConfig(("077_rubiks_cube",), (0,), (0.0,), 1, tuple(METHODS)),
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

        def spec_for(method: str) -> dict[str, Any]:
            weight, fingers = METHODS[method]
            return {
                "allocator": "qp",
                "gravity": True,
                "balance_weight": weight,
                "gravity_compensation": fingers,
            }

        # The perturbation study's design and seeds: the same pull axes.
        variants = [({"method": m}, spec_for(m)) for m in cfg.methods]
        return pull_jobs(cfg, seed, hand, protocol, variants)
