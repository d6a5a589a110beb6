"""Reach-grasp-hold-regrasp episodes (paper Sec. III-D and Table I), many seeds, five objects.

Each job is one ``wholehand reach`` episode (:mod:`wholehand.reaching.episode`) on one of the
paper's five objects, with the force regulation as in the paper (``qp``: no external wrench
balanced) or balancing the object's known weight (``qp+weight``), and the latter with the
reacher keeping the fingers apart (``qp+weight+self``). Per method: acquisition
success (a first grasp was made), time to grasp, losses per perturbation, regrasp success
(losses followed by a new grasp) and episodes completed (held at the end).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from wholehand.errors import ConfigError
from wholehand.models.object_catalogue import PAPER_OBJECTS
from wholehand.studies.base import DEFAULT_HAND, Study, TrialJob, derive_seed, group_rows
from wholehand.trials.outcome import sim_warnings_error
from wholehand.trials.trial import TrialSpec


@dataclass(frozen=True)
class Method:
    balance_weight: bool
    """Force regulation balances the object's weight."""
    self_collision: bool = False
    """The reacher keeps the fingers apart."""
    tracker: bool = False
    """The object pose as the robot's tracker gives it (:data:`TRACKER`)."""
    deadline: float = 0.0
    """The QP allocator's deadline [s] (0: none)."""
    predict: float = 0.0
    """With the tracker: the controller's pose prediction, at most this long [s] (0: none)."""
    person_sees: str = "stage"
    """How the person judges a grasp before letting go (``EpisodeSpec.person_sees``)."""
    hand_servo: str = "step"
    """Where the fingers' targets are servoed (``EpisodeSpec.hand_servo``)."""


TRACKER = (30.0, 0.033)
"""The robot path's tracker: frames at 30 Hz with 33 ms latency (``hw-sim``'s default)."""
PREDICTION = 0.1
"""The controller's longest pose prediction [s] (``PosePredictor``'s default)."""
ROBOT_DEADLINE = 0.002
"""The robot controller's QP deadline [s] (``control --qp-deadline``'s default)."""


METHODS = {
    "qp": Method(False),
    "qp+weight": Method(True),
    "qp+weight+self": Method(True, self_collision=True),
}
"""Method label -> how the episode runs."""

CONDITIONS = {
    "in-process": Method(True),
    "tracker": Method(True, tracker=True),
    "deadline": Method(True, deadline=ROBOT_DEADLINE),
    "tracker+deadline": Method(True, tracker=True, deadline=ROBOT_DEADLINE),
    "tracker+predict": Method(True, tracker=True, predict=PREDICTION),
    "tracker+predict+touch": Method(True, tracker=True, predict=PREDICTION, person_sees="contacts"),
    "tracker+predict+servo": Method(True, tracker=True, predict=PREDICTION, hand_servo="command"),
}
"""The robot-conditions study's variants: the in-process episode with the robot path's
conditions added one at a time (label -> how the episode runs)."""


@dataclass(frozen=True)
class ReachConfig:
    objects: tuple[str, ...]
    episodes: int
    """Seeded episodes per object and method."""
    methods: tuple[str, ...] = tuple(METHODS)


CONFIGS = {
    "full": ReachConfig(PAPER_OBJECTS, 10),
    "quick": ReachConfig(PAPER_OBJECTS, 1),
    "tiny": ReachConfig(("077_rubiks_cube",), 1, ("qp+weight",)),
}


def episode_row(job: TrialJob) -> dict[str, Any]:
    """Run the job's episode; its outcome columns."""
    from wholehand.reaching.episode import run_episode
    from wholehand.reaching.episode_spec import EpisodeSpec

    s = job.spec
    # --methods puts plain allocator names in the label: those run the paper's balance
    method = {**METHODS, **CONDITIONS}.get(job.labels["method"], METHODS["qp"])
    tracker_rate, tracker_latency = TRACKER if method.tracker else (0.0, 0.0)
    started = time.perf_counter()
    summary = run_episode(
        EpisodeSpec(
            hand=s.hand,
            object=s.object,
            seed=s.seed,
            rate=s.control_rate,
            allocator=str(s.allocator),
            balance_weight=method.balance_weight,
            self_collision=method.self_collision,
            start=str(job.labels.get("start", "held")),
            tracker_rate=tracker_rate,
            tracker_latency=tracker_latency,
            tracker_predict=method.predict,
            qp_deadline=method.deadline,
            person_sees=method.person_sees,
            hand_servo=method.hand_servo,
        )
    )
    warnings = summary["mujoco_warnings"]
    loop = summary["loop"]
    cycles = max(int(loop["cycles"]), 1)
    return {
        "held": bool(summary["complete"]),
        "acquired": summary["grasps"] > 0,
        "time_to_grasp_s": summary["time_to_grasp_s"],
        "grasps": summary["grasps"],
        "losses": summary["losses"],
        "losses_snatch": summary["loss_causes"].count("snatch"),
        "losses_release": summary["loss_causes"].count("gravity"),
        "loss_causes": " ".join(summary["loss_causes"]),
        "recovered": summary["recovered"],
        "perturbations": summary["perturbations"],
        "duration_s": round(float(summary["duration_s"]), 6),
        "cycles": int(loop["cycles"]),
        "stage_errors": int(loop["n_errors"]),
        "reacher_relaxed": int(summary["reacher_faults"].get("relaxed", 0)),
        "reacher_held": int(summary["reacher_faults"].get("held", 0)),
        "step_retries": int(warnings.get("step_retries", 0)),
        "step_retries_failed": int(warnings.get("step_retries_failed", 0)),
        "failure_stage": "" if summary["complete"] else "episode",
        "error": sim_warnings_error(warnings),
        "wall_time_s": time.perf_counter() - started,
        "cycle_mean_us": 1e6 * (time.perf_counter() - started) / cycles,
    }


def _counts(group: list[dict[str, Any]]) -> dict[str, Any]:
    """Episode counts of a group of rows: acquisition, time to grasp, losses (all, and those
    not caused by the snatch, which is meant to take the object), regrasps, completions."""
    times = [float(r["time_to_grasp_s"]) for r in group if r["acquired"]]
    losses = sum(int(r["losses"]) for r in group)
    snatch = sum(int(r["losses_snatch"]) for r in group)
    perturbations = sum(int(r["perturbations"]) for r in group)
    recovered = sum(int(r["recovered"]) for r in group)
    return {
        "episodes": len(group),
        "acquired": sum(bool(r["acquired"]) for r in group),
        "time_to_grasp_s_median": float(np.median(times)) if times else float("nan"),
        "perturbations": perturbations,
        "losses": losses,
        "losses_not_snatch": losses - snatch,
        "losses_at_release": sum(int(r.get("losses_release", 0)) for r in group),
        "losses_per_perturbation": losses / perturbations if perturbations else 0.0,
        "recovered": recovered,
        "step_retries_failed": sum(int(r.get("step_retries_failed", 0)) for r in group),
        "reacher_relaxed": sum(int(r.get("reacher_relaxed", 0)) for r in group),
        "regrasp_success": recovered / losses if losses else float("nan"),
        "completed": sum(bool(r["held"]) for r in group),
    }


class ReachStudy(Study):
    name = "reach"
    description = (
        "seeded reach-grasp-hold-regrasp episodes with gravity on the paper's five objects: "
        "acquisition, time to grasp, losses per perturbation, regrasps (Sec. III-D, Table I)"
    )

    start = "held"
    """Where each episode's object starts (``EpisodeSpec.start``)."""

    def objects(self, cfg: ReachConfig, hand: str) -> tuple[str, ...]:
        """The objects of a study of this size for ``hand``."""
        return cfg.objects

    def methods(self, cfg: ReachConfig) -> tuple[str, ...]:
        """The method labels each object and seed runs under (:data:`METHODS`' or the
        size's)."""
        return cfg.methods

    def jobs(self, size: str, seed: int, hand: str = DEFAULT_HAND) -> list[TrialJob]:
        cfg = CONFIGS[self.check_size(size)]
        jobs: list[TrialJob] = []
        for oi, obj in enumerate(self.objects(cfg, hand)):
            for episode in range(cfg.episodes):
                episode_seed = derive_seed(seed, oi, episode)
                for method in self.methods(cfg):
                    spec = TrialSpec(hand=hand, object=obj, seed=episode_seed, gravity=True)
                    labels: dict[str, Any] = {"method": method, "episode": episode}
                    if self.start != "held":
                        labels["start"] = self.start
                    jobs.append(TrialJob(len(jobs), spec, labels, "episode"))
        return jobs

    def summarise(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        valid = [r for r in rows if not r.get("error")]
        groups = [
            {"method": method, **_counts(group)}
            for (method,), group in group_rows(valid, "method").items()
        ]
        by_object = [
            {"method": method, "object": obj, **_counts(group)}
            for (method, obj), group in group_rows(valid, "method", "object").items()
        ]
        return {"groups": groups, "by_object": by_object, "n_excluded": len(rows) - len(valid)}

    def plot(self, rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> None:
        from matplotlib.figure import Figure

        g = summary["groups"]
        names = ("acquired", "completed")
        fig = Figure(figsize=(8, 3.2))
        axes = fig.subplots(1, 2)
        xs = np.arange(len(g))
        width = 0.8 / len(names)
        for i, name in enumerate(names):
            share = [100.0 * x[name] / max(x["episodes"], 1) for x in g]
            axes[0].bar(xs + (i - 0.5) * width, share, width, label=name)
        axes[0].set_ylabel("episodes [%]")
        axes[0].set_ylim(0, 105)
        axes[0].legend(fontsize=7)
        axes[1].bar(xs - 0.2, [x["losses"] for x in g], 0.4, label="losses")
        axes[1].bar(xs + 0.2, [x["recovered"] for x in g], 0.4, label="recovered")
        axes[1].set_ylabel("count")
        axes[1].legend(fontsize=7)
        for ax in axes:
            ax.set_xticks(xs, [x["method"] for x in g])
        fig.tight_layout()
        fig.savefig(path, dpi=120)


class ReachTableStudy(ReachStudy):
    """The reach study with the object resting on the table (``wholehand reach --start
    table``), on those of the study's objects the hand has table-top grasps of (in any grasp
    style)."""

    name = "reach-table"
    description = (
        "the reach study from the table (wholehand reach --start table): the paper's objects "
        "that have table-top grasps (wholehand grasps generate --on-table)"
    )
    start = "table"

    def objects(self, cfg: ReachConfig, hand: str) -> tuple[str, ...]:
        from wholehand.grasps.store import grasp_file
        from wholehand.reaching.pipeline import grasp_hand_of
        from wholehand.studies.models import model

        styles = grasp_hand_of(model("hand", hand)).config.grasp_styles
        found = tuple(
            o
            for o in cfg.objects
            if any(grasp_file(hand, o, style, on_table=True).is_file() for style in styles)
        )
        if not found:
            raise ConfigError(
                f"hand {hand!r} has no table-top grasps of {list(cfg.objects)}; make some with "
                f"`wholehand grasps generate --hand {hand} --on-table --method optimize "
                "--object NAME`"
            )
        return found


class RobotConditionsStudy(ReachStudy):
    """Which of the robot path's conditions costs grasps: the reach episode in process (as
    ``wholehand reach`` and ``bench pipeline``'s in-process half run it, the object's weight
    balanced), then with the tracker the robot double has (30 Hz, 33 ms), with the robot
    controller's 2 ms QP deadline, and with both, on the same seeds; then behind the tracker with
    the controller's pose prediction, and with that and a person who lets go once the thumb and
    two fingers touch the object (``tracker+predict+touch``: the robot double's person before
    the controller published its stage), and with the fingers' targets servoed by the
    controller at its rate (``tracker+predict+servo``: a hand without a position interface on
    the robot). The deadline is on wall time: those rows depend on the computer, as the robot's
    do."""

    name = "robot-conditions"
    description = (
        "the reach episode in process with the robot path's conditions added one at a time "
        "(tracker 30 Hz / 33 ms, 2 ms QP deadline, both, pose prediction, a person who lets go "
        "on touch, the fingers servoed at the control rate): which one costs grasps"
    )

    def methods(self, cfg: ReachConfig) -> tuple[str, ...]:
        """Every condition of :data:`CONDITIONS`, whatever the size."""
        return tuple(CONDITIONS)
