"""On-disk cache for precomputed data (link surface samples, object SDF grids).

Entries are ``.npz`` files named by a SHA-256 content hash of everything the data depends on
(file bytes and parameters), so a changed URDF, mesh or parameter can never hit a stale entry.
The cache lives in ``$WHOLEHAND_CACHE`` if set, else ``~/.cache/wholehand``.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

CACHE_VERSION = 1
"""Bumped whenever the layout or the algorithm behind a cached entry changes."""


def cache_dir() -> Path:
    """The cache directory, created on first use."""
    root = os.environ.get("WHOLEHAND_CACHE")
    path = Path(root).expanduser() if root else Path("~/.cache/wholehand").expanduser()
    path.mkdir(parents=True, exist_ok=True)
    return path


def content_hash(*parts: bytes | str | Path | dict[str, Any] | float | int) -> str:
    """SHA-256 hex digest over file contents (for paths), bytes, strings, numbers and dicts."""
    h = hashlib.sha256(f"wholehand-cache-v{CACHE_VERSION}".encode())
    for part in parts:
        if isinstance(part, Path):
            h.update(b"file:" + part.read_bytes())
        elif isinstance(part, bytes):
            h.update(b"bytes:" + part)
        elif isinstance(part, dict):
            h.update(b"dict:" + json.dumps(part, sort_keys=True, default=str).encode())
        else:
            h.update(f"{type(part).__name__}:{part!r}".encode())
    return h.hexdigest()


def load_arrays(kind: str, key: str) -> dict[str, np.ndarray] | None:
    """The arrays stored under ``kind``/``key``, or None on a miss or an unreadable entry."""
    path = cache_dir() / kind / f"{key}.npz"
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            return {name: data[name] for name in data.files}
    except (OSError, ValueError):
        return None  # a truncated or corrupt entry is recomputed


def save_arrays(kind: str, key: str, arrays: dict[str, np.ndarray]) -> Path:
    """Store arrays under ``kind``/``key`` atomically (safe with parallel writers)."""
    folder = cache_dir() / kind
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{key}.npz"
    fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp.npz")
    os.close(fd)
    try:
        np.savez_compressed(tmp, **arrays)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path
