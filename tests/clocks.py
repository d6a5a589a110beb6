"""A clock a test runs ahead instead of sleeping through a timeout."""

from __future__ import annotations

import threading
import time


class RunAheadClock:
    """``time.monotonic`` plus however far the test has run it ahead [s]: monotonic, so the
    code under test sees time pass as it would, but a test moves past a timeout at once and
    exactly."""

    def __init__(self) -> None:
        self._ahead = 0.0
        self._lock = threading.Lock()

    def __call__(self) -> float:
        with self._lock:
            return time.monotonic() + self._ahead

    def advance(self, seconds: float) -> None:
        with self._lock:
            self._ahead += seconds
