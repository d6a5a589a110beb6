"""Exception hierarchy of wholehand.

Every error raised on purpose by the library derives from :class:`WholehandError`, so a user can
catch one type. Messages name the file, link, joint or value at fault and say how to fix it;
errors from the libraries underneath are wrapped with ``raise ... from err``.
"""

from __future__ import annotations


class WholehandError(Exception):
    """Root of every error raised on purpose by wholehand."""


class ConfigError(WholehandError):
    """A configuration file or argument is malformed or names something that does not exist."""


class AssetError(WholehandError):
    """A URDF, mesh or other asset is missing, unreadable or unusable as it is."""


class PluginError(WholehandError):
    """A plug-in cannot be found, imported or constructed."""


class ObservationError(WholehandError):
    """An observation is unusable (NaN or inf, wrong shape, not a rigid pose, a stamp the joint
    history does not cover). Inside the control loop it becomes a status, a count and a logged
    reason, and the last feasible command is kept; it never ends a run."""
