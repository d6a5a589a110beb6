"""Real-time scheduling of the controller's control thread (``[rates] thread_priority``) and a
heap the garbage collector leaves alone while the loop runs.

On a computer that runs other programs beside the controller (the robot's drivers, a tracker, a
recorder), the operating system may preempt the control thread for a few milliseconds and a
cycle comes past its period. Linux's ``SCHED_FIFO`` policy runs a ready thread of a higher
priority before every normal one, as ros2_control's controller manager runs its update thread
(its ``thread_priority``, 50 by default on a real-time kernel). Only the control thread gets it:
the transport's threads that deliver the robot's messages, and the watchdog, keep the normal
policy. The loop sleeps between cycles, so the other programs keep the rest of the time.

Python's cyclic garbage collector, when it collects its oldest generation, walks every
container object the process holds: 30-50 ms with the models, plans and caches of an arm-hand
controller (about 180,000 objects), a pause of several cycles. :func:`frozen_heap` collects
once before the loop and moves what is left out of the collector's way (``gc.freeze``), so
that a collection in the loop walks only the objects the loop made.

Setting the priority needs the ``CAP_SYS_NICE`` capability or a real-time priority limit for
the user (``ulimit -r``, or ``rtprio`` in /etc/security/limits.conf); a priority the computer
refuses is a :class:`~wholehand.errors.ConfigError` before the robot is commanded.
"""

from __future__ import annotations

import gc
import os
from collections.abc import Iterator
from contextlib import contextmanager

from wholehand.errors import ConfigError

MAX_PRIORITY = 99
"""The highest ``SCHED_FIFO`` priority Linux accepts."""


@contextmanager
def realtime_priority(priority: int) -> Iterator[None]:
    """Run the calling thread under ``SCHED_FIFO`` at ``priority`` (1-99) inside the block and
    under its previous policy after; ``priority`` 0 leaves the scheduling as it is.

    Raises:
        ConfigError: the priority is outside 0-99, the operating system has no ``SCHED_FIFO``,
            or it refused the priority (the message names the fix).
    """
    if priority == 0:
        yield
        return
    if not 1 <= priority <= MAX_PRIORITY:
        raise ConfigError(f"[rates] thread_priority must be 0 (off) or 1-99, got {priority}")
    if not hasattr(os, "sched_setscheduler"):
        raise ConfigError(
            "[rates] thread_priority needs Linux's SCHED_FIFO scheduling, which this operating "
            "system does not offer; set thread_priority = 0"
        )
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as err:
        raise ConfigError(
            f"[rates] thread_priority = {priority}: the operating system refused SCHED_FIFO "
            f"({err.strerror}); give the user a real-time priority limit (`ulimit -r "
            f"{priority}`, or `rtprio {priority}` in /etc/security/limits.conf), run with the "
            "CAP_SYS_NICE capability, or set thread_priority = 0"
        ) from None
    try:
        yield
    finally:
        os.sched_setscheduler(0, policy, param)


def check_priority(priority: int) -> None:
    """Raise the :class:`~wholehand.errors.ConfigError` :func:`realtime_priority` would, now:
    before the robot's streams are opened (whose threads would inherit the policy if the
    control thread held it then)."""
    with realtime_priority(priority):
        pass


@contextmanager
def frozen_heap() -> Iterator[None]:
    """Collect the garbage, then keep every object alive now out of the collector's walks
    inside the block (``gc.freeze``); the objects frozen here are collectable again after."""
    gc.collect()
    before = gc.get_freeze_count()
    gc.freeze()
    try:
        yield
    finally:
        if before == 0:
            gc.unfreeze()
