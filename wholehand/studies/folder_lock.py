"""One writer per study folder.

Two runs of ``wholehand study`` on the same ``--out`` would both append to its journal and the
last to finish would write the results. :func:`study_folder_lock` holds an advisory lock on
``<folder>/.study.lock`` (``flock``) for the whole run and writes who holds it there; a second
run is refused with the holder named. The operating system releases the lock when the holder
exits, however it exits (a killed run leaves no stale lock). Where ``fcntl`` does not exist
(Windows) runs are not locked.
"""

from __future__ import annotations

import os
import socket
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from wholehand.errors import ConfigError

LOCK_NAME = ".study.lock"
"""The lock file in a study's output folder."""


@contextmanager
def study_folder_lock(folder: Path) -> Iterator[None]:
    """Hold ``folder`` (which must exist) for this run.

    Raises:
        ConfigError: another run holds it (the message names its process, host, start time
            and command).
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        yield
        return
    path = folder / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        holder = os.read(fd, 4096).decode("utf-8", "replace").strip() or "a process"
        os.close(fd)
        raise ConfigError(
            f"{folder} is in use by another study run ({holder}); wait for it to end, stop "
            "it, or write to another --out"
        ) from None
    try:
        started = time.strftime("%Y-%m-%d %H:%M:%S")
        command = " ".join(sys.argv) or "python"
        os.ftruncate(fd, 0)
        os.write(
            fd, f"pid {os.getpid()} on {socket.gethostname()} since {started}: {command}".encode()
        )
        yield
    finally:
        os.ftruncate(fd, 0)
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)
