"""Validators of hand.toml values shared by the hand and assembly parsers."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

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
        f"({'[m]' if key.endswith('xyz') else '[rad]'}), e.g. {key} = [0.0, 0.0, 0.0]; "
        f"got {value!r}"
    )
