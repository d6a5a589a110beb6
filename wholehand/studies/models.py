"""Hands and objects loaded once per process (a study's workers run many trials each)."""

from __future__ import annotations

from typing import Any

_MODELS: dict[tuple[str, str], Any] = {}
"""Per-process cache of loaded hands and objects (worker processes run many trials)."""


def model(kind: str, name: str) -> Any:
    """A hand (``kind="hand"``) or object model by name, loaded once per process."""
    key = (kind, name)
    if key not in _MODELS:
        if kind == "hand":
            from wholehand.models.hand import load_hand

            _MODELS[key] = load_hand(name)
        else:
            from wholehand.models.object_catalogue import load_object

            _MODELS[key] = load_object(name)
    return _MODELS[key]
