"""Further tests a generated grasp must pass to be kept, beyond the generator's validation."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Sequence

from wholehand.grasps.store import Grasp

GraspCheck = Callable[[Grasp], "str | None"]
"""A further test of a grasp that passed validation (e.g.
:func:`~wholehand.trials.hold_check.protocol_check`): None to keep it, or the reason it fails,
counted among the rejections."""


def passes(grasp: Grasp, check: GraspCheck | None, rejections: Counter[str]) -> Grasp | None:
    """``grasp`` if it passes ``check`` (or there is none), else None with the reason counted
    in ``rejections``."""
    reason = check(grasp) if check is not None else None
    if reason is not None:
        rejections[reason] += 1
        return None
    return grasp


def all_of(checks: Sequence[GraspCheck]) -> GraspCheck | None:
    """One check that applies ``checks`` in turn and fails with the first one's reason;
    None when there are none."""
    if not checks:
        return None
    if len(checks) == 1:
        return checks[0]

    def check(grasp: Grasp) -> str | None:
        for one in checks:
            reason = one(grasp)
            if reason is not None:
                return reason
        return None

    return check
