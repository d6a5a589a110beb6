"""A grasp kept only if force regulation holds it through the perturbation protocol.

For ``wholehand grasps generate --require-hold DEG``: a grasp that settles in the generator's
validation can still be lost under the paper's loads and pull. :func:`protocol_check` runs the
protocol of ``wholehand run`` (gravity off, ``mesh_sdf`` + ``qp``, seed 0) on each grasp the
generator would keep and rejects those lost, naming the phase.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from wholehand.grasps.store import Grasp
from wholehand.models.hand import HandModel
from wholehand.models.objects import ObjectModel
from wholehand.trials.outcome import outcome_of
from wholehand.trials.trial import TrialSpec, run_trial


def protocol_check(
    hand: HandModel, obj: ObjectModel, theta_deg: float, spec: TrialSpec | None = None
) -> Callable[[Grasp], str | None]:
    """A grasp check (:data:`~wholehand.grasps.checks.GraspCheck`): None when the grasp is
    held through the protocol with a rotational pull of ``theta_deg`` [deg], else the reason
    (the phase it was lost in). ``spec`` sets the other trial parameters (default: those of
    ``wholehand run``); its hand, object and grasp are replaced."""
    trial = dataclasses.replace(
        spec or TrialSpec(), hand=hand.config.reference, object=obj.name, theta_deg=theta_deg
    )

    def check(grasp: Grasp) -> str | None:
        outcome = outcome_of(run_trial(trial, hand, obj, grasp=grasp))
        if outcome.held:
            return None
        if outcome.error:
            return f"the protocol failed: {outcome.error}"
        return f"lost in the {theta_deg:g} deg protocol (phase {outcome.failure_phase})"

    return check
