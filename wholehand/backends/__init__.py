"""Backends: simulation or hardware the control loop runs over."""

from wholehand.backends.base import (
    Backend,
    HasGroundTruth,
    PushesObject,
    ReportsWarnings,
    Resettable,
)

__all__ = ["Backend", "HasGroundTruth", "PushesObject", "ReportsWarnings", "Resettable"]
