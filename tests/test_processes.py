"""The helper that waits for a child's line: it returns on the line, fails on silence or exit
instead of blocking, and leaves what follows the line to ``communicate()``."""

from __future__ import annotations

import subprocess
import sys

import pytest
from processes import wait_for_line


def child(code: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def test_it_returns_on_the_line_and_leaves_the_rest():
    proc = child(
        "import sys, time\n"
        "sys.stderr.write('first\\nstreams up\\nafter\\n'); sys.stderr.flush(); time.sleep(30)"
    )
    try:
        wait_for_line(proc, "streams up", timeout=60.0)
    finally:
        proc.kill()
    _, err = proc.communicate(timeout=30)
    assert err == "after\n"


def test_a_silent_child_fails_the_wait_instead_of_hanging_it():
    proc = child("import time; time.sleep(30)")
    try:
        with pytest.raises(pytest.fail.Exception, match="no 'streams up' .* within 0.5 s"):
            wait_for_line(proc, "streams up", timeout=0.5)
    finally:
        proc.kill()
        proc.communicate(timeout=30)


def test_a_child_that_exits_without_the_line_fails_with_its_last_lines():
    proc = child("import sys; sys.stderr.write('no robot found\\n')")
    with pytest.raises(pytest.fail.Exception, match="no robot found"):
        wait_for_line(proc, "streams up", timeout=60.0)
    proc.communicate(timeout=30)
