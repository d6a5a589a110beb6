"""wholehand commands as processes, for the tests that run a controller beside the robot double."""

from __future__ import annotations

import os
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


def wait_for_line(proc: subprocess.Popen[str], text: str, timeout: float = 120.0) -> None:
    """Read the process's stderr until a line holds ``text``; fail the test if it never does."""
    deadline = time.monotonic() + timeout
    assert proc.stderr is not None
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if text in line:
            return
        if not line and proc.poll() is not None:
            break
    pytest.fail(f"no {text!r} from {proc.args[3] if len(proc.args) > 3 else 'the process'}")
