"""Argument types that check a number when the command line is parsed, before a command joins
a network, builds a model or starts a run: a bad value is argparse's one-line error (exit 2)
naming the option and what it takes."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def _number(kind: type, test: Callable[[float], bool], want: str) -> Callable[[str], float]:
    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {want}") from None
        if not (math.isfinite(value) and test(value)):
            raise argparse.ArgumentTypeError(f"{text} is not {want}")
        return value

    parse.__name__ = want  # argparse names the type by it in its messages
    return parse


seconds = _number(float, lambda v: v >= 0.0, "a time >= 0 [s]")
"""A finite time of at least zero [s]."""
positive_seconds = _number(float, lambda v: v > 0.0, "a time > 0 [s]")
"""A finite time above zero [s]."""
count = _number(int, lambda v: v >= 1, "a whole number >= 1")
"""A whole number of at least one."""
natural = _number(int, lambda v: v >= 0, "a whole number >= 0")
"""A whole number of at least zero (a seed, an index)."""
rate = _number(float, lambda v: v > 0.0, "a rate > 0 [Hz]")
"""A finite rate above zero [Hz]."""


def add_joint_gaps(p: argparse.ArgumentParser, of: str) -> None:
    """``--joint-gap START DURATION`` (repeatable, times >= 0): the robot double sends no joint
    states for DURATION s from START s ``of`` what (e.g. "of each episode")."""
    p.add_argument(
        "--joint-gap",
        nargs=2,
        action="append",
        type=seconds,
        metavar=("START", "DURATION"),
        help=f"the double sends no joint states for DURATION s from START s {of} (a stalled "
        "driver; repeatable)",
    )


def joint_gaps(args: argparse.Namespace) -> tuple[tuple[float, float], ...]:
    """The ``--joint-gap`` options as ``(start, duration)`` pairs [s]."""
    return tuple((float(a), float(b)) for a, b in args.joint_gap or ())
