"""Benchmark of the force-allocation QP (``wholehand bench allocate``).

Problems are synthetic but shaped like the paper's (Sec. IV-C, K sweep: 14 to 91 contacts;
:mod:`wholehand.bench.synthetic_grasps`).

Per solver and contact count, two modes are timed with ``perf_counter_ns`` around the whole
``allocate()`` call (problem building included), after a warm-up:

- ``warm``: one allocator over a control-loop-like sequence, contact points jittered by 0.1 mm
  about their nominal positions each cycle (normals and Jacobians recomputed);
- ``no_warm_start``: the same with ``warm_start=False`` (no primal start, no remembered working
  set), persistent solver objects kept: isolates the effect of the warm start;
- ``cold``: the same sequence with ``reset()`` before every call (no warm start, no kept solver
  object).

DAQP is also timed with the edge weights screened (``screen_edges: true``) and without
constraint screening (``screening: false``) for the A/B.

The yardstick (``direct``): the paper's QP posed directly on the local forces
(:func:`~wholehand.allocation.reference.direct_problem`: dense Hessian ``G^T G``, four friction
rows per contact, every torque and consistency row) and solved by each installed ``qpsolvers``
solver, timed over the same warm sequence from the contacts to the solution (building the
problem included, as for the allocator). ``speedup`` gives, per N, the best direct time over the
best allocator time (p50).

The paper's baseline (``paper_form``): the form the paper's lab solves with
OSQP, forces and residual wrench as variables with the wrench as equality rows
(:func:`~wholehand.allocation.reference.paper_lab_problem`), timed the same way; ``speedup``
gives the best allocator's p50 and p99 against it.
"""

from __future__ import annotations

import os
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np
import numpy.typing as npt

from wholehand import registry
from wholehand.allocation.base import Allocator
from wholehand.allocation.options import SolveOptions
from wholehand.bench.synthetic_grasps import SyntheticGrasp, synthetic_grasp
from wholehand.provenance import provenance

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

MODES: tuple[str, ...] = ("warm", "no_warm_start", "cold")
"""Timed modes, see the module docstring."""


def _versions() -> dict[str, Any]:
    out: dict[str, Any] = provenance()
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        out[var] = os.environ.get(var, "")
    return out


def _time_mode(
    grasp: SyntheticGrasp,
    make: Any,
    cycles: int,
    warmup: int,
    seed: int,
    mode: str,
) -> dict[str, Any]:
    from wholehand.timing import percentiles_us

    rng = np.random.default_rng(seed + 1)
    inputs = [grasp.cycle(rng, 1e-4) for _ in range(warmup + cycles)]
    alloc = make(warm_start=mode != "no_warm_start")
    cold = mode == "cold"
    samples = np.empty(cycles, dtype=np.int64)
    solve = np.empty(cycles)
    statuses: Counter[str] = Counter()
    rounds = []
    residual = []
    violation = 0.0
    for i, (contacts, J, com) in enumerate(inputs):
        if cold:
            alloc.reset()
        t0 = time.perf_counter_ns()
        out = alloc.allocate(contacts, J, com)
        dt = time.perf_counter_ns() - t0
        if i < warmup:
            continue
        k = i - warmup
        samples[k] = dt
        solve[k] = out.solve_time
        statuses[out.status.value] += 1
        sol = alloc.last_solution
        if sol is not None:
            rounds.append(sol.rounds)
            if out.fresh:
                violation = max(violation, sol.violation)
        residual.append(float(np.linalg.norm(out.residual_wrench)))
    stats: dict[str, Any] = dict(percentiles_us(samples))
    stats["solve_p50_us"] = round(float(np.median(solve)) * 1e6, 2)
    stats["status"] = dict(statuses)
    stats["rounds_mean"] = round(float(np.mean(rounds)), 3) if rounds else 0.0
    stats["max_violation"] = float(violation)
    stats["residual_norm_p50"] = float(np.median(residual))
    return stats


def _time_direct(
    grasp: SyntheticGrasp,
    solver: str,
    params: Any,
    cycles: int,
    warmup: int,
    seed: int,
    form: str = "direct",
) -> dict[str, Any]:
    """The ``form`` (``direct``: :func:`~wholehand.allocation.reference.direct_problem`;
    ``paper``: :func:`~wholehand.allocation.reference.paper_lab_problem`) built and solved by
    ``solver`` over the warm sequence, timed from the contacts to the solution."""
    import warnings

    import qpsolvers

    from wholehand.allocation.problem import build_allocation_qp
    from wholehand.allocation.reference import direct_problem, paper_lab_problem
    from wholehand.allocation.solvers.qpsolvers_solver import QpsolversSolver
    from wholehand.timing import percentiles_us

    settings = dict(QpsolversSolver.solver_defaults.get(solver, {}))
    rng = np.random.default_rng(seed + 1)
    inputs = [grasp.cycle(rng, 1e-4) for _ in range(warmup + cycles)]
    samples = np.empty(cycles, dtype=np.int64)
    found = 0
    for i, (contacts, J, com) in enumerate(inputs):
        t0 = time.perf_counter_ns()
        qp = build_allocation_qp(contacts, J, com, params)
        problem = paper_lab_problem(qp) if form == "paper" else direct_problem(qp)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sol = qpsolvers.solve_problem(problem, solver=solver, **settings)
        dt = time.perf_counter_ns() - t0
        if i >= warmup:
            samples[i - warmup] = dt
            found += bool(sol.found)
    return {**percentiles_us(samples), "found": found}


def run_allocation_benchmark(
    contact_counts: Sequence[int] = (14, 45, 90),
    solvers: Sequence[str] | None = None,
    cycles: int = 300,
    warmup: int = 30,
    seed: int = 0,
    out_dir: str | Path | None = None,
    unscreened: bool = True,
    allocator_kwargs: dict[str, Any] | None = None,
    direct_solvers: Sequence[str] = ("daqp", "osqp", "piqp", "proxqp", "clarabel", "quadprog"),
) -> dict[str, Any]:
    """Time ``QPAllocator.allocate`` per solver, contact count and mode (see :data:`MODES`).

    Args:
        contact_counts: Numbers of contacts N.
        solvers: Solver names (default: ``dual_active_set`` and the natively driven ones that
            are installed).
        cycles: Timed cycles per (solver, N, mode).
        warmup: Untimed cycles before them.
        seed: Seed of the problems and jitter.
        out_dir: Folder for ``allocate.json`` and ``allocate.png``; None writes nothing.
        unscreened: Also time DAQP without constraint screening (A/B).
        allocator_kwargs: Extra ``QPAllocator`` keyword arguments (e.g. ``tau_max``).
        direct_solvers: ``qpsolvers`` solvers for the direct form (the installed ones are
            timed); empty: no yardstick.

    Returns:
        JSON-able dict: ``config``, ``environment``, ``results`` (one entry per solver, mode
        of :data:`MODES`, screening and N with p50/p95/p99/mean/max [us] of the whole
        ``allocate()`` call, ``solve_p50_us`` from ``Allocation.solve_time``, status counts,
        mean screening rounds, largest accepted constraint violation and median residual-wrench
        norm), ``best`` (per N, the fastest warm configuration), ``direct`` (the direct form
        per solver and N), ``speedup`` (per N: best direct p50 / best allocator p50, counting
        only solvers that solved every cycle) and ``plot`` (PNG path or None).
    """
    from wholehand.allocation.solvers import NATIVE_SOLVERS, STRUCTURED_SOLVERS

    names = list(solvers) if solvers is not None else [*STRUCTURED_SOLVERS, *NATIVE_SOLVERS]
    extra = dict(allocator_kwargs or {})
    configs: list[tuple[str, bool, bool]] = [(s, True, False) for s in names]
    if "daqp" in names:
        configs.append(("daqp", True, True))
        if unscreened:
            configs.append(("daqp", False, False))
    results = [
        row
        for n in contact_counts
        for row in _allocator_rows(int(n), configs, extra, cycles, warmup, seed)
    ]
    best = _best_warm(results, contact_counts)
    direct, paper, speedup = _direct_rows(
        contact_counts, direct_solvers, extra, best, cycles, warmup, seed
    )
    report: dict[str, Any] = {
        "config": {
            "contact_counts": [int(n) for n in contact_counts],
            "solvers": names,
            "cycles": cycles,
            "warmup": warmup,
            "seed": seed,
            "allocator_kwargs": {k: repr(v) for k, v in extra.items()},
            "timed": "whole QPAllocator.allocate() call, perf_counter_ns",
        },
        "environment": _versions(),
        "results": results,
        "best": best,
        "direct": direct,
        "paper_form": paper,
        "speedup": speedup,
        "plot": None,
    }
    if out_dir is not None:
        import json

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        report["plot"] = str(_plot(results, out / "allocate.png"))
        (out / "allocate.json").write_text(json.dumps(report, indent=2))
    return report


def _allocator_rows(
    n: int,
    configs: list[tuple[str, bool, bool]],
    extra: dict[str, Any],
    cycles: int,
    warmup: int,
    seed: int,
) -> list[dict[str, Any]]:
    """One row per (solver, screening, edge screening) of ``configs`` and mode of
    :data:`MODES` at ``n`` contacts."""
    qp_allocator = registry.get_class("allocators", "qp")
    grasp = synthetic_grasp(seed, n)
    rows: list[dict[str, Any]] = []
    for solver, screening, edges in configs:
        qp_allocator(options={"solver": solver}, **extra)  # fail early on a bad name

        def make(
            warm_start: bool,
            solver: str = solver,
            screening: bool = screening,
            edges: bool = edges,
        ) -> Allocator:
            options = SolveOptions(
                solver=solver, screening=screening, screen_edges=edges, warm_start=warm_start
            )
            return cast(Allocator, qp_allocator(options=options, **extra))

        for mode in MODES:
            stats = _time_mode(grasp, make, cycles, warmup, seed, mode)
            config = {"solver": solver, "screening": screening, "screen_edges": edges}
            rows.append(config | {"mode": mode, "n_contacts": n} | stats)
    return rows


def _best_warm(results: list[dict[str, Any]], contact_counts: Sequence[int]) -> dict[str, Any]:
    """Per contact count, the warm configuration with the lowest p50."""
    best: dict[str, Any] = {}
    for n in contact_counts:
        rows = [r for r in results if r["n_contacts"] == n and r["mode"] == "warm"]
        if rows:
            b = min(rows, key=lambda r: r["p50_us"])
            keys = ("solver", "screening", "screen_edges", "p50_us", "p99_us")
            best[str(n)] = {k: b[k] for k in keys}
    return best


def _direct_rows(
    contact_counts: Sequence[int],
    direct_solvers: Sequence[str],
    extra: dict[str, Any],
    best: dict[str, Any],
    cycles: int,
    warmup: int,
    seed: int,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], dict[str, Any]]:
    """The direct form timed per installed solver of ``direct_solvers`` and contact count, the
    paper's form with OSQP per count, and per count the best direct p50 and the paper form's
    p50 and p99 over the best allocator's (direct: solvers that solved every cycle only)."""
    direct: list[dict[str, Any]] = []
    paper_rows: list[dict[str, Any]] = []
    speedup: dict[str, Any] = {}
    if not direct_solvers:
        return direct, paper_rows, speedup
    import qpsolvers

    from wholehand.allocation.problem import AllocationParams

    fields = set(AllocationParams.__dataclass_fields__)
    params = AllocationParams.checked(
        "bench allocate", **{k: v for k, v in extra.items() if k in fields}
    )
    chosen = [s for s in direct_solvers if s in qpsolvers.available_solvers]
    for n in contact_counts:
        grasp = synthetic_grasp(seed, int(n))
        for solver in chosen:
            stats = _time_direct(grasp, solver, params, cycles, warmup, seed)
            direct.append({"solver": solver, "n_contacts": int(n)} | stats)
        rows = [r for r in direct if r["n_contacts"] == n and r["found"] == cycles]
        if rows and str(n) in best:
            d = min(rows, key=lambda r: r["p50_us"])
            speedup[str(n)] = {
                "allocator_p50_us": best[str(n)]["p50_us"],
                "direct_solver": d["solver"],
                "direct_p50_us": d["p50_us"],
                "ratio": round(d["p50_us"] / best[str(n)]["p50_us"], 2),
            }
        if "osqp" in qpsolvers.available_solvers and str(n) in best:
            paper = _time_direct(grasp, "osqp", params, cycles, warmup, seed, form="paper")
            b = best[str(n)]
            paper_rows.append({"solver": "osqp", "n_contacts": int(n)} | paper)
            speedup[str(n)] = speedup.get(str(n), {}) | {
                "paper_form_p50_us": paper["p50_us"],
                "paper_form_p99_us": paper["p99_us"],
                "paper_ratio_p50": round(paper["p50_us"] / b["p50_us"], 2),
                "paper_ratio_p99": round(paper["p99_us"] / b["p99_us"], 2),
            }
    return direct, paper_rows, speedup


def _plot(results: list[dict[str, Any]], path: Path) -> Path:
    import matplotlib
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10.5, 4.2))

    (ax50, ax99) = fig.subplots(1, 2, sharey=True)
    keys = sorted({(r["solver"], r["screening"], r["screen_edges"]) for r in results})
    colors = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    styles = {"warm": "-", "no_warm_start": ":", "cold": "--"}
    for i, key in enumerate(keys):
        solver, screening, edges = key
        label = solver if screening else f"{solver} (no screening)"
        label += ", edges screened" if edges else ""
        for mode, style in styles.items():
            rows = sorted(
                (
                    r
                    for r in results
                    if (r["solver"], r["screening"], r["screen_edges"]) == key and r["mode"] == mode
                ),
                key=lambda r: r["n_contacts"],
            )
            if not rows:
                continue
            x = [r["n_contacts"] for r in rows]
            kw = {"marker": "o", "color": colors[i % len(colors)]}
            ax50.plot(x, [r["p50_us"] for r in rows], style, label=f"{label}, {mode}", **kw)
            if mode == "warm":
                ax99.plot(x, [r["p99_us"] for r in rows], style, label=f"{label}, {mode}", **kw)
    for ax, what in ((ax50, "p50, every mode"), (ax99, "p99, warm")):
        ax.set_xlabel("contacts N")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.set_title(f"allocate() time per cycle ({what})", fontsize=10)
    ax50.set_ylabel("time [us]")
    ax50.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    return path


__all__ = ["run_allocation_benchmark"]
