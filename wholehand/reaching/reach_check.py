"""A grasp kept only if the reacher closes it: ``wholehand grasps generate --require-reach S``.

A grasp that settles in the generator's validation (the hand placed at the grasp and closed)
can still close poorly at the end of a reach: the fingers arrive from the pre-grasp, a little
off, while the person slides the object, and touch with too few of them for the stage machine
to hand over, or knock the object over. :func:`reach_check` runs the episode of ``wholehand
reach`` with only that grasp to reach for, from seeded starts, up to the person's move and (in
the air) letting go, without the push, the twist and the snatch; it rejects the grasp unless
every start closes it within the limit and keeps it for :data:`HOLD` after.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from wholehand.backends.table import HAND_MARGIN
from wholehand.errors import ConfigError
from wholehand.grasps.store import Grasp
from wholehand.models.grasp_styles import style_arrays
from wholehand.models.hand import HandModel
from wholehand.models.objects import ObjectModel
from wholehand.reaching.episode import episode_scene, run_episode
from wholehand.reaching.episode_spec import EpisodeSpec
from wholehand.reaching.pregrasp import plan_pregrasp, usable_on_table

HOLD: float = 1.0
"""How long the hand must keep the grasp after closing [s]: the episode runs this long past
the time limit."""
SEEDS: tuple[int, ...] = (0, 1, 2, 3, 4)
"""The episode seeds each grasp is reached from (the start's offset, the person's move and, on
a table, the object's yaw)."""

LOST_AFTER: dict[str, str] = {
    "other": "once the person left it on the table",
    "gravity": "once the person let go",
    "move": "as the person moved it",
    "none": "before the person did anything",
    "push": "while it held it, unloaded",  # the check's push and twist are of zero size
    "twist": "while it held it, unloaded",
}
"""A loss's cause (:func:`~wholehand.reaching.person.loss_cause`) in a rejection's words."""


def reach_check(
    hand: HandModel,
    obj: ObjectModel,
    style: str,
    within: float,
    on_table: bool,
    seeds: Sequence[int] = SEEDS,
) -> Callable[[Grasp], str | None]:
    """A grasp check (:data:`~wholehand.grasps.checks.GraspCheck`): None when the reacher
    closes the grasp within ``within`` [s] of the episode's start and keeps it for at least
    :data:`HOLD` (no loss before the episode ends at ``within + HOLD``), from each of
    ``seeds``; else the reason. ``style``: the grasp style the grasps are made with (its
    fingers must touch to close); ``on_table``: the object rests on the table (the grasps are
    table-top grasps) rather than being held out by the person.

    Raises:
        ConfigError: ``within`` is not a positive number of seconds, no seed is given, or the
            hand has no grasp style ``style``.
    """
    if not (math.isfinite(within) and within > 0):
        raise ConfigError(f"--require-reach must be > 0 [s], got {within!r}")
    if not seeds:
        raise ConfigError("reach_check: give at least one seed")
    styles = hand.config.grasp_styles
    if style not in styles:
        raise ConfigError(
            f"hand {hand.name!r} has no grasp style {style!r}; its styles: {sorted(styles)}"
        )
    q_open = style_arrays(hand, styles["power"])[0]
    grasp_style = None if style == "power" else styles[style]

    def check(grasp: Grasp) -> str | None:
        plan = plan_pregrasp(hand, obj, grasp, q_open, style=grasp_style)
        if plan is None:
            return "no pre-grasp clears the object"
        for seed in seeds:
            spec = EpisodeSpec(
                hand=hand.name,
                object=obj.name,
                seed=seed,
                start="table" if on_table else "held",
                duration=within + HOLD,
                push=0.0,
                twist=0.0,
            )
            scene = episode_scene(spec, hand, obj, [plan])
            if not usable_on_table(hand, plan, scene.wMo, scene.table, HAND_MARGIN):
                return "the grasp or its pre-grasp comes too near the table"
            summary = run_episode(spec, scene=scene)
            closed_at = summary["time_to_grasp_s"]
            if closed_at is None or closed_at > within:
                return f"the reacher did not close it within {within:g} s"
            # A snatch within the episode's time (a grasp closed early) is the person's, not a loss.
            lost = [c for c in summary["loss_causes"] if c != "snatch"]
            if lost:
                return f"lost after the reacher closed it ({LOST_AFTER.get(lost[0], lost[0])})"
        return None

    return check
