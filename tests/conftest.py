"""Shared fixtures: an isolated on-disk cache and the shipped hand, loaded once per session;
the ``realtime`` marker and the ``--realtime`` option that runs its tests apart."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

# One cache folder for the whole test session, never the user's own cache.
_SESSION_CACHE = Path(tempfile.mkdtemp(prefix="wholehand-test-cache-"))
os.environ["WHOLEHAND_CACHE"] = str(_SESSION_CACHE)


REALTIME = (
    "a verdict about the computer: it needs one that keeps up in real time (run apart, on an "
    "otherwise idle computer: pytest --realtime)"
)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--realtime",
        action="store_true",
        help="run only the tests marked realtime (process tests whose verdict needs a computer "
        "that keeps up in real time); without it they are skipped",
    )


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", f"realtime: {REALTIME}")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Without ``--realtime`` the realtime tests are skipped (with the reason); with it, they
    alone run."""
    if config.getoption("--realtime"):
        others = [item for item in items if "realtime" not in item.keywords]
        if others:
            config.hook.pytest_deselected(items=others)
            items[:] = [item for item in items if "realtime" in item.keywords]
        return
    skip = pytest.mark.skip(reason=REALTIME)
    for item in items:
        if "realtime" in item.keywords:
            item.add_marker(skip)


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
