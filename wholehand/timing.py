"""Latency statistics: percentiles (the one helper every benchmark and summary uses), timed
calls with warm-up."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np

OVER_US = 1000.0
"""Duration counted as over a 1 kHz period [us] (``n_over_1ms``)."""


def percentiles(
    values: Sequence[float] | np.ndarray, points: Sequence[float] = (50, 99)
) -> dict[str, float]:
    """``{"p50": ..., "p99": ..., "max": ..., "n": ...}`` of ``values`` at ``points`` [%], in
    the values' unit; ``{}`` when there are none."""
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        return {}
    out = {f"p{p:g}": float(q) for p, q in zip(points, np.percentile(v, points), strict=True)}
    return {**out, "max": float(v.max()), "n": int(v.size)}


def percentiles_us(samples_ns: Sequence[int] | np.ndarray) -> dict[str, float]:
    """:func:`percentiles` (p50/p95/p99/p99.9, max) of durations given in ns, reported in
    microseconds with a ``_us`` suffix and rounded to 0.01 us, with their mean, the sample
    count ``n`` and ``n_over_1ms``, how many took longer than :data:`OVER_US`."""
    us = np.asarray(samples_ns, dtype=float) / 1e3
    if us.size == 0:
        return {"p50_us": float("nan"), "p95_us": float("nan"), "p99_us": float("nan")}
    stats = percentiles(us, (50, 95, 99, 99.9))
    n = stats.pop("n")
    out = {f"{key}_us": round(value, 2) for key, value in stats.items()}
    out["mean_us"] = round(float(us.mean()), 2)
    out["max_us"] = out.pop("max_us")  # the mean before the max, the benchmarks' key order
    return {**out, "n": int(n), "n_over_1ms": int(np.count_nonzero(us > OVER_US))}


def time_calls(fn: Callable[[int], object], count: int, warmup: int = 50) -> np.ndarray:
    """Durations [ns] of ``fn(i)`` for i in range(count), after ``warmup`` untimed calls."""
    for i in range(warmup):
        fn(i % max(count, 1))
    out = np.empty(count, dtype=np.int64)
    for i in range(count):
        start = time.perf_counter_ns()
        fn(i)
        out[i] = time.perf_counter_ns() - start
    return out
