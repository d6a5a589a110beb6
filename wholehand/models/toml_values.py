"""Validators of hand.toml values shared by the hand and assembly parsers."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, overload

from wholehand.errors import ConfigError


def three_numbers(
    value: Any, key: str, where: Path, table: str = "[mount]"
) -> tuple[float, float, float]:
    ok = isinstance(value, list) and len(value) == 3
    if ok and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        x, y, z = (float(v) for v in value)
        if all(map(math.isfinite, (x, y, z))):
            return x, y, z
    raise ConfigError(
        f"{where}: {table} {key} must be a list of 3 finite numbers "
        f"({'[m]' if key.endswith('xyz') else '[rad]' if key.endswith('rpy') else '[-]'}), "
        f"e.g. {key} = [0.0, 0.0, 0.0]; "
        f"got {value!r}"
    )


@overload
def str_list(
    table: dict[str, Any], key: str, where: Path, default: list[str]
) -> tuple[str, ...]: ...


@overload
def str_list(
    table: dict[str, Any], key: str, where: Path, default: None = None
) -> tuple[str, ...] | None: ...


def str_list(
    table: dict[str, Any], key: str, where: Path, default: list[str] | None = None
) -> tuple[str, ...] | None:
    """``table[key]`` as a tuple of names, else ``default``; anything else is a ConfigError."""
    value = table.get(key, default)
    if value is None:
        return None
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{where}: {key!r} must be a list of names, got {value!r}")
    return tuple(value)


def number(value: Any, what: str, where: Path, positive: bool = False) -> float:
    """``value`` as a float: a finite number, >= 0 (> 0 if ``positive``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{where}: {what} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(f"{where}: {what} must be a finite number, got {value!r}")
    if positive and not value > 0:
        raise ConfigError(f"{where}: {what} must be > 0, got {value!r}")
    if value < 0:
        raise ConfigError(f"{where}: {what} must be >= 0, got {value!r}")
    return float(value)


def joint_numbers(table: Any, what: str, where: Path) -> dict[str, float]:
    """A table of joint name -> number as a dict of floats."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: {what} must be a table of joint name -> number")
    out = {}
    for joint, value in table.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: {what}.{joint} must be a number, got {value!r}")
        out[joint] = float(value)
    return out
