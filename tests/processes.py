"""wholehand commands as processes, for the tests that run a controller beside the robot double."""

from __future__ import annotations

import os
import selectors
import signal
import subprocess
import sys
import time

import pytest


def wholehand(*args: str) -> subprocess.Popen[str]:
    """``wholehand <args>`` in a new process, its output piped."""
    return subprocess.Popen(
        [sys.executable, "-m", "wholehand.cli.main", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=os.environ.copy(),
    )


def interrupt(proc: subprocess.Popen[str], timeout: float = 60.0) -> str:
    """SIGINT to ``proc``, as Ctrl-C; its stderr once it has exited (within ``timeout`` [s])."""
    proc.send_signal(signal.SIGINT)
    return proc.communicate(timeout=timeout)[1]


def kill_running(*procs: subprocess.Popen[str] | None) -> None:
    """Kill those of ``procs`` still running (None skipped), so that a failed test leaves no
    process behind."""
    for proc in procs:
        if proc is not None and proc.poll() is None:
            proc.kill()


def wait_for_line(proc: subprocess.Popen[str], text: str, timeout: float = 120.0) -> None:
    """Read the process's stderr until a line holds ``text``; fail the test if none does within
    ``timeout`` [s]. Reads byte by byte once the pipe has one (no read blocks: a child that
    prints nothing cannot hang the test), and nothing past the line, which ``communicate()``
    still gets."""
    assert proc.stderr is not None
    deadline = time.monotonic() + timeout
    fd = proc.stderr.fileno()
    line, seen = bytearray(), []
    with selectors.DefaultSelector() as selector:
        selector.register(fd, selectors.EVENT_READ)
        while (left := deadline - time.monotonic()) > 0.0:
            if not selector.select(left):
                break  # the deadline passed with nothing to read
            byte = os.read(fd, 1)
            if not byte:  # end of the pipe: the process exited
                break
            if byte != b"\n":
                line += byte
                continue
            seen.append(line.decode(errors="replace"))
            if text in seen[-1]:
                return
            line.clear()
    name = proc.args[3] if isinstance(proc.args, list) and len(proc.args) > 3 else "the process"
    pytest.fail(f"no {text!r} from {name} within {timeout:g} s; its last lines: {seen[-5:]}")
