"""Backends: simulation or hardware the control loop runs over."""

from wholehand.backends.base import Backend, HandObjectState

__all__ = ["Backend", "HandObjectState"]
