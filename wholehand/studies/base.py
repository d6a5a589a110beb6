"""What a study is: a named, seeded expansion into trial jobs, a summary and a plot."""

from __future__ import annotations

import abc
import dataclasses
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from wholehand.errors import ConfigError
from wholehand.trials.outcome import DIVERGED_PREFIX
from wholehand.trials.trial import TrialSpec

FloatArray = npt.NDArray[np.float64]

SIZES = ("tiny", "quick", "full")
"""Study sizes: ``full`` is the paper's design; ``quick`` a < 2 min subset on 2 cores;
``tiny`` a seconds-long smoke configuration for tests."""


DEFAULT_HAND = TrialSpec().hand
"""The hand of the paper's studies as published here (the Allegro)."""

METHODS = ("qp", "fingertip_only", "feedforward", "impedance")
"""Methods of the perturbation and contact-count studies: ours, the fingertip-only ablation and
the two non-adaptive baselines."""

QUICK_PROTOCOL: dict[str, float] = {"settle_time": 0.3, "load_duration": 0.15, "rotation_time": 0.5}
"""Shortened protocol of ``quick`` studies [s] (the paper's: 0.5 s settle, 1 s per load
direction, 1.5 s pull)."""
TINY_PROTOCOL: dict[str, float] = {"settle_time": 0.1, "load_duration": 0.05, "rotation_time": 0.2}
"""Protocol of ``tiny`` smoke studies [s]."""


def protocol_for(size: str) -> dict[str, float]:
    """``protocol_params`` overrides of a study size (empty: the paper's protocol)."""
    return {"tiny": dict(TINY_PROTOCOL), "quick": dict(QUICK_PROTOCOL), "full": {}}[size]


def derive_seed(seed: int, *keys: int) -> int:
    """A 31-bit seed derived from the study seed and integer keys (object, grasp, repeat).

    Methods share seeds for the same keys, so they face the same random pull axes (paired).
    """
    return int(np.random.SeedSequence([int(seed), *map(int, keys)]).generate_state(1)[0] >> 1)


@dataclass(frozen=True)
class TrialJob:
    """One unit of work of a study: a trial spec plus the labels the study groups by."""

    index: int
    """Position in the study; rows are written in this order."""
    spec: TrialSpec
    labels: dict[str, Any] = field(default_factory=dict)
    """Study-specific columns, e.g. ``{"method": "qp"}`` or ``{"k": 5}``."""
    kind: str = "trial"
    """What to run: ``"trial"`` (:func:`wholehand.trials.trial.run_trial`) or a measurement
    registered in :data:`wholehand.studies.runner.JOB_KINDS`."""


class Study(abc.ABC):
    """A named experiment of the paper: jobs per size and seed, a summary, a plot."""

    name: str = ""
    description: str = ""

    @abc.abstractmethod
    def jobs(self, size: str, seed: int, hand: str = DEFAULT_HAND) -> list[TrialJob]:
        """The study's trials for a size (see :data:`SIZES`), seeded by ``seed``, on ``hand``
        (a shipped hand's name or a hand folder): the grasps of the design that it has."""

    @abc.abstractmethod
    def summarise(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        """Aggregate results (JSON-serialisable) from the per-trial rows."""

    @abc.abstractmethod
    def plot(self, rows: list[dict[str, Any]], summary: dict[str, Any], path: Path) -> None:
        """Write the study's figure (PNG) to ``path``."""

    @staticmethod
    def check_size(size: str) -> str:
        if size not in SIZES:
            raise ConfigError(f"study size {size!r} is unknown; use one of {list(SIZES)}")
        return size


def _grasp_rates(rows: list[dict[str, Any]], held: Any) -> FloatArray:
    per_grasp: dict[tuple[str, str, str, int], list[bool]] = {}
    for r in rows:
        key = (r["hand"], r["object"], r.get("grasp_type", "power"), int(r["grasp"]))
        per_grasp.setdefault(key, []).append(held(r))
    return np.array([np.mean(v) for v in per_grasp.values()], dtype=float)


def success_stats(rows: list[dict[str, Any]]) -> dict[str, float | int]:
    """Success rate over grasps: the mean of grasp-level rates, +- 1 standard error across them.

    A grasp is one (hand, object, grasp type, grasp) entry; its rate is the fraction of its
    trials held.
    Rows with an ``error`` (the trial raised, or its simulation diverged) say nothing about the
    controller: they are left out and counted in ``n_excluded``. Because divergence is not
    independent of the method, ``success_diverged_lost`` is the same rate with diverged trials
    counted as lost (trials that raised are still left out); ``n_diverged`` counts them.
    ``success_strict`` and ``se_strict``: the same with the strict criterion
    (:attr:`~wholehand.trials.outcome.RunOutcome.held_strict`), NaN where a row lacks it.
    """
    valid = [r for r in rows if not r.get("error")]  # failed or diverged runs are excluded
    diverged = [r for r in rows if str(r.get("error") or "").startswith(DIVERGED_PREFIX)]
    rates = _grasp_rates(valid, lambda r: bool(r["held"]))
    rates_lost = _grasp_rates(valid + diverged, lambda r: not r.get("error") and bool(r["held"]))
    n = int(rates.size)
    # The strict criterion's rate (slip within bounds too), where every row carries it (rows
    # of studies run before it did not).
    carried = all(isinstance(r.get("held_strict"), bool) for r in valid)
    strict = _grasp_rates(valid, lambda r: r["held_strict"]) if carried else np.zeros(0)
    n_strict = int(strict.size)
    return {
        "success": float(rates.mean()) if n else float("nan"),
        "se": float(rates.std(ddof=1) / np.sqrt(n)) if n > 1 else 0.0,
        "success_strict": float(strict.mean()) if n_strict else float("nan"),
        "se_strict": float(strict.std(ddof=1) / np.sqrt(n_strict)) if n_strict > 1 else 0.0,
        "success_diverged_lost": float(rates_lost.mean()) if rates_lost.size else float("nan"),
        "n_grasps": n,
        "n_trials": len(valid),
        "n_excluded": len(rows) - len(valid),
        "n_diverged": len(diverged),
    }


def trials_label(summary: dict[str, Any]) -> str:
    """``"<size>, N trials"``, or ``"<size>, N of M trials"`` for a partial run, preceded by
    the hand's name when it is not the default one."""
    n, planned = summary["n_trials"], summary.get("n_planned", summary["n_trials"])
    label = (
        f"{summary['size']}, {n} trials"
        if n == planned
        else f"{summary['size']}, {n} of {planned} trials"
    )
    hand = summary.get("hand", DEFAULT_HAND)
    return label if hand == DEFAULT_HAND else f"{Path(hand).name}, {label}"


def save_success_figure(fig: Any, ax: Any, path: Path, title: str | None = None) -> None:
    """Finish a success-rate plot (axis label and range, title, legend) and write it as PNG."""

    ax.set_ylabel("success [%]")
    ax.set_ylim(-5, 105)
    if title:
        ax.set_title("\n".join(textwrap.wrap(title, 48)), fontsize=10)
    if ax.get_legend_handles_labels()[0]:  # a partial run may have no line yet
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def with_methods(jobs: list[TrialJob], methods: tuple[str, ...]) -> list[TrialJob]:
    """The study's jobs with its methods replaced by ``methods`` (registered allocators, a
    third party's included): every job of the study's first method is repeated for each of
    ``methods``, in place; the other methods' jobs are dropped. Indices are renumbered.

    Raises:
        ConfigError: the study compares no methods (its jobs have no ``method`` label), or a
            method is not a registered allocator.
    """
    from wholehand import registry

    if not methods:
        raise ConfigError("--methods needs at least one allocator name")
    for name in methods:
        registry.get_class("allocators", name)  # an unknown name raises, listing the known
    labelled = [j for j in jobs if "method" in j.labels]
    if jobs and not labelled:
        raise ConfigError("this study compares no methods; --methods does not apply to it")
    template = labelled[0].labels["method"] if labelled else None
    out: list[TrialJob] = []
    for job in jobs:
        if job.labels.get("method", template) != template:
            continue
        choices: tuple[str | None, ...] = tuple(methods) if "method" in job.labels else (None,)
        for method in choices:
            if method is None:
                out.append(dataclasses.replace(job, index=len(out)))
                continue
            spec = dataclasses.replace(job.spec, allocator=method)
            labels = {**job.labels, "method": method}
            out.append(dataclasses.replace(job, index=len(out), spec=spec, labels=labels))
    return out


def with_grasps(jobs: list[TrialJob], folder: str | Path) -> list[TrialJob]:
    """The study's trials on the grasps in ``folder/<object>.json`` (e.g. written by
    ``wholehand grasps generate --out folder``) instead of the hand's stored ones. A trial
    whose grasp index is past the folder's file of its object, or whose object has no file
    there, is dropped; other jobs are kept. Indices are renumbered.

    Raises:
        ConfigError: ``folder`` is not a folder, or it holds a grasp file of none of the
            study's objects.
    """
    from wholehand.grasps.store import load_grasps, object_key

    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(f"grasp folder {folder} does not exist; pass a folder of <object>.json")
    counts: dict[Path, int] = {}
    out: list[TrialJob] = []
    n_replaced = 0
    for job in jobs:
        if job.kind != "trial" or job.spec.grasp_file:
            out.append(dataclasses.replace(job, index=len(out)))
            continue
        path = folder / f"{object_key(job.spec.object)}.json"
        if path not in counts:
            counts[path] = len(load_grasps(path)) if path.is_file() else 0
        if job.spec.grasp >= counts[path]:
            continue
        spec = dataclasses.replace(job.spec, grasp_file=str(path))
        out.append(dataclasses.replace(job, index=len(out), spec=spec))
        n_replaced += 1
    if jobs and not n_replaced:
        wanted = sorted({object_key(j.spec.object) for j in jobs if j.kind == "trial"})
        held = sorted(p.stem for p in folder.glob("*.json"))
        raise ConfigError(
            f"grasp folder {folder} holds grasps of {held or 'no object'}, none of the "
            f"study's objects {wanted}; write them with `wholehand grasps generate --object "
            f"NAME --out {folder}`"
        )
    return out


def only_jobs(jobs: list[TrialJob], only: dict[str, tuple[str, ...]]) -> list[TrialJob]:
    """The jobs whose labels or spec columns (:data:`wholehand.studies.rows.SPEC_COLUMNS`) match
    ``only``: for every key one of its values (numbers compare as numbers: ``theta_deg=90``
    matches 90.0). Other jobs are dropped; indices are renumbered, seeds kept, so the rows
    are those of the same trials of the whole design.

    Raises:
        ConfigError: a key that is neither a label nor a spec column of the study's trials, or
            no job left.
    """
    from wholehand.studies.rows import spec_columns

    def cells(job: TrialJob) -> dict[str, Any]:
        return {**spec_columns(job.spec), **job.labels}

    def same(cell: Any, text: str) -> bool:
        if isinstance(cell, bool) or not isinstance(cell, int | float):
            return str(cell) == text
        try:
            return float(cell) == float(text)
        except ValueError:
            return False

    known = set().union(*(cells(j) for j in jobs)) if jobs else set()
    for key in only:
        if key not in known:
            raise ConfigError(
                f"--only {key}=...: the study's trials have no column {key!r}; "
                f"use one of {sorted(known)}"
            )
    out: list[TrialJob] = []
    for job in jobs:
        row = cells(job)
        if all(any(same(row.get(k), v) for v in values) for k, values in only.items()):
            out.append(dataclasses.replace(job, index=len(out)))
    if jobs and not out:
        wanted = ", ".join(f"{k} in {list(v)}" for k, v in only.items())
        raise ConfigError(f"no trial of the study has {wanted}; check the values")
    return out


def group_rows(
    rows: list[dict[str, Any]], *keys: str
) -> dict[tuple[Any, ...], list[dict[str, Any]]]:
    """Rows grouped by the values of ``keys``, groups in first-seen order."""
    out: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for r in rows:
        out.setdefault(tuple(r[k] for k in keys), []).append(r)
    return out
