"""Shared fixtures: an isolated on-disk cache and the shipped hand, loaded once per session."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

# One cache folder for the whole test session, never the user's own cache.
_SESSION_CACHE = Path(tempfile.mkdtemp(prefix="wholehand-test-cache-"))
os.environ["WHOLEHAND_CACHE"] = str(_SESSION_CACHE)


@pytest.fixture(scope="session")
def allegro():
    from wholehand.models.hand import load_hand

    return load_hand("allegro_right")


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    """An empty cache folder for tests that count cache hits."""
    folder = tmp_path / "cache"
    monkeypatch.setenv("WHOLEHAND_CACHE", str(folder))
    return folder
