"""On-disk cache for precomputed data (link surface samples, object SDF grids).

Entries are ``.npz`` files named by a SHA-256 content hash of everything the data depends on
(file bytes and parameters), so a changed URDF, mesh or parameter can never hit a stale entry.
The cache lives in ``$WHOLEHAND_CACHE`` if set, else ``~/.cache/wholehand``.

The cache never stops a command: an entry that cannot be read (truncated, empty, not an npz,
other arrays than expected) is reported and recomputed; a cache folder that cannot be created or
written (read-only, a file in its place) is reported once and the data is computed without
caching.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

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


def text_file(kind: str, stem: str, text: str, suffix: str) -> Path:
    """``text`` written once as ``<cache>/<kind>/<stem>-<hash>.<suffix>`` (in the temporary
    folder if the cache folder is unusable), for parsers that read a file (a merged URDF, a
    self-contained MJCF); its path."""
    name = f"{stem}-{content_hash(text)[:16]}.{suffix}"
    try:
        folder = cache_dir() / kind
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        folder = Path(tempfile.gettempdir())
    path = folder / name
    if not path.is_file() or path.read_text() != text:
        # A temporary file of its own: study workers may write the same file at once.
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=name, suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    return path


_UNREADABLE = (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError)
"""What reading a damaged ``.npz`` raises (numpy, zipfile and the file system)."""

_warned_folders: set[str] = set()


def _folder_unusable(err: OSError) -> None:
    where = os.environ.get("WHOLEHAND_CACHE") or "~/.cache/wholehand"
    if where not in _warned_folders:
        _warned_folders.add(where)
        log.warning(
            "the wholehand cache %s cannot be used (%s); computing without it: set "
            "WHOLEHAND_CACHE to a writable folder",
            where,
            err,
        )


def load_arrays(
    kind: str, key: str, names: Iterable[str] | None = None
) -> dict[str, np.ndarray] | None:
    """The arrays stored under ``kind``/``key``, or None on a miss; an entry that cannot be read,
    or (when ``names`` is given) that holds other arrays than ``names``, is reported and treated
    as a miss (the caller recomputes and overwrites it)."""
    try:
        path = cache_dir() / kind / f"{key}.npz"
    except OSError as err:
        _folder_unusable(err)
        return None
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except _UNREADABLE as err:
        log.warning(
            "cache entry %s is unreadable (%s: %s); recomputing it", path, type(err).__name__, err
        )
        return None
    if names is not None and set(arrays) != set(names):
        log.warning(
            "cache entry %s holds arrays %s, expected %s; recomputing it",
            path,
            sorted(arrays),
            sorted(names),
        )
        return None
    return arrays


def save_arrays(kind: str, key: str, arrays: dict[str, np.ndarray]) -> Path | None:
    """Store arrays under ``kind``/``key`` atomically (safe with parallel writers); None when the
    cache cannot be written (reported once)."""
    try:
        folder = cache_dir() / kind
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{key}.npz"
        fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp.npz")
    except OSError as err:
        _folder_unusable(err)
        return None
    os.close(fd)
    try:
        np.savez_compressed(tmp, allow_pickle=False, **arrays)
        os.replace(tmp, path)
    except OSError as err:
        _folder_unusable(err)
        return None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path
