"""Ending a robot-side run on a signal: SIGINT (Ctrl-C) and SIGTERM set an event instead of
raising, and the loop ends at its next cycle, so that every exit writes its summary (and the
controller its exit ramp)."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

from wholehand.loop.control_loop import Cycle, Observer


@contextlib.contextmanager
def signals_set(stopped: threading.Event) -> Iterator[None]:
    """While the block runs, SIGINT and SIGTERM set ``stopped`` instead of raising; only the
    main thread can set signal handlers, elsewhere nothing changes."""
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda *_: stopped.set())
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


class StopOnEvent(Observer):
    """Ends the loop (``"stopped"``) at the first cycle after ``event`` is set."""

    def __init__(self, event: threading.Event) -> None:
        self.event = event

    def on_cycle(self, cycle: Cycle) -> str | None:
        return "stopped" if self.event.is_set() else None
