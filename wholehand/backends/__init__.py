"""Backends: simulation or hardware the control loop runs over."""

from wholehand.backends.base import Backend, HandObjectState, PerturbableBackend

__all__ = ["Backend", "HandObjectState", "PerturbableBackend"]
