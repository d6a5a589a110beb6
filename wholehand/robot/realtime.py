"""Real-time scheduling of the controller's control thread (``[rates] thread_priority``) and a
heap the garbage collector leaves alone while the loop runs.

On a computer that runs other programs beside the controller (the robot's drivers, a tracker, a
recorder), the operating system may preempt the control thread for a few milliseconds and a
cycle comes past its period. Linux's ``SCHED_FIFO`` policy runs a ready thread of a higher
priority before every normal one, as ros2_control's controller manager runs its update thread
(its ``thread_priority``, 50 by default on a real-time kernel). The loop sleeps between cycles,
so the other programs keep the rest of the time.

The transport's threads that deliver the robot's messages run Python (the decoding and checks
of :mod:`wholehand.ros2.streams`), so they hold the interpreter's lock while they do. Preempted
by another program in the middle of a message, such a thread keeps the lock, and the control
thread, however high its priority, waits for it: a priority inversion, a control cycle late by
the scheduler's time slice (4-14 ms seen on 2 cores shared with the robot double). Each of
those threads is raised to one priority below the control thread's when it first delivers a
message (:class:`DeliveryPriority`); the watchdog keeps the normal policy.

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
import logging
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from wholehand.errors import ConfigError

log = logging.getLogger(__name__)

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


def delivery_priority(priority: int) -> int:
    """The ``SCHED_FIFO`` priority of the threads that deliver messages when the control thread
    runs at ``priority``: one below it (at least 1), 0 (normal scheduling) when it is 0."""
    return 0 if priority == 0 else max(1, priority - 1)


class DeliveryPriority:
    """Raises each thread that calls it to ``SCHED_FIFO`` at ``priority`` the first time it
    calls (module docstring); ``priority`` 0 does nothing. Called from the transport's threads,
    so it never raises: a refusal (checked beforehand by :func:`check_priority`, so only if the
    limits changed since) is logged once and counted.

    Attributes:
        raised: threads raised so far.
        refused: threads whose raise the operating system refused.
    """

    def __init__(self, priority: int) -> None:
        if not 0 <= priority <= MAX_PRIORITY:
            raise ConfigError(
                f"DeliveryPriority: priority must be 0-{MAX_PRIORITY}, got {priority}"
            )
        self.priority = priority
        self.raised = 0
        self.refused = 0
        self._seen = threading.local()
        self._count = threading.Lock()

    def __call__(self) -> None:
        if self.priority == 0 or getattr(self._seen, "done", False):
            return
        self._seen.done = True
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.priority))
        except (OSError, AttributeError) as err:  # AttributeError: no SCHED_FIFO here
            with self._count:
                self.refused += 1
                first = self.refused == 1
            if first:
                log.warning(
                    "could not raise a message-delivery thread to SCHED_FIFO %d (%s); it keeps "
                    "the normal scheduling",
                    self.priority,
                    err,
                )
            return
        with self._count:
            self.raised += 1


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
