"""What made a result: the commit, the library versions and the CPU, for every study summary and
benchmark that docs cite."""

from __future__ import annotations

import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path
from typing import Any

LIBRARIES = (
    "numpy", "scipy", "numba", "mujoco", "pin", "coal", "qpsolvers", "daqp", "osqp", "piqp",
    "mink", "eclipse-zenoh", "rosbags",
)  # fmt: skip
"""Distributions whose versions change numbers or timings."""


def commit() -> str:
    """The git commit of the wholehand source in use, with ``+dirty`` when it has uncommitted
    changes; ``"unknown"`` outside a git checkout."""
    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"],
            capture_output=True, text=True, timeout=5, check=True,
        ).stdout.strip()  # fmt: skip
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True, text=True, timeout=5, check=True,
        ).stdout.strip()  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux), else what the platform says."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def provenance() -> dict[str, Any]:
    """JSON-ready: ``commit``, ``python``, ``versions`` of :data:`LIBRARIES` (None when not
    installed), ``cpu`` and ``cpu_count``."""
    import os

    versions: dict[str, str | None] = {}
    for name in LIBRARIES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return {
        "commit": commit(),
        "python": sys.version.split()[0],
        "versions": versions,
        "cpu": cpu_model(),
        "cpu_count": os.cpu_count(),
    }
