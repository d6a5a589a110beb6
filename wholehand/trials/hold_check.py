"""A grasp kept only if force regulation holds it through the perturbation protocol.

For ``wholehand grasps generate --require-hold DEG``: a grasp that settles in the generator's
validation can still be lost under the paper's loads and pull. :func:`protocol_check` runs the
protocol of ``wholehand run`` (gravity off, ``mesh_sdf`` + ``qp``, seed 0) on each grasp the
generator would keep and rejects those lost, naming the phase. With several trials, the pulls
go about the random axes of seeds 0, 1, ... and the grasp must hold in a stated share of them.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Callable

from wholehand.grasps.store import Grasp
from wholehand.models.hand import HandModel
from wholehand.models.objects import ObjectModel
from wholehand.trials.outcome import outcome_of
from wholehand.trials.trial import TrialSpec, run_trial


def protocol_check(
    hand: HandModel,
    obj: ObjectModel,
    theta_deg: float,
    spec: TrialSpec | None = None,
    trials: int = 1,
    min_rate: float = 0.8,
) -> Callable[[Grasp], str | None]:
    """A grasp check (:data:`~wholehand.grasps.checks.GraspCheck`): None when the grasp is
    held through the protocol with a rotational pull of ``theta_deg`` [deg], else the reason
    (the phase it was lost in). With ``trials`` > 1 the protocol runs with the seeds
    ``spec.seed``, ``spec.seed + 1``, ... (the pull's axis) and the grasp must be held in at
    least ``min_rate`` of them (stopping once that is reached or out of reach). ``spec`` sets
    the other trial parameters (default: those of ``wholehand run``); its hand, object and
    grasp are replaced.

    Raises:
        ValueError: ``trials`` < 1 or ``min_rate`` outside (0, 1].
    """
    if trials < 1 or not 0.0 < min_rate <= 1.0:
        raise ValueError(f"trials >= 1 and 0 < min_rate <= 1, got {trials} and {min_rate}")
    trial = dataclasses.replace(
        spec or TrialSpec(), hand=hand.config.reference, object=obj.name, theta_deg=theta_deg
    )
    needed = math.ceil(min_rate * trials - 1e-9)

    def check(grasp: Grasp) -> str | None:
        held, lost_in = 0, Counter[str]()
        for k in range(trials):
            seeded = dataclasses.replace(trial, seed=trial.seed + k)
            outcome = outcome_of(run_trial(seeded, hand, obj, grasp=grasp))
            if outcome.error:
                return f"the protocol failed: {outcome.error}"
            if outcome.held:
                held += 1
            else:
                lost_in[str(outcome.failure_phase)] += 1
            if held >= needed:
                return None
            if held + trials - k - 1 < needed:
                break
        phase = lost_in.most_common(1)[0][0]
        if trials == 1:
            return f"lost in the {theta_deg:g} deg protocol (phase {phase})"
        return (
            f"held in fewer than {needed} of {trials} {theta_deg:g} deg protocols "
            f"(most often lost in phase {phase})"
        )

    return check
