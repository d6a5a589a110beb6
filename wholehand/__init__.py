"""wholehand: real-time force regulation of whole-hand dexterous grasps.

Conventions used everywhere: poses are 4x4 homogeneous numpy arrays named ``aMb`` (pose of
frame b expressed in frame a; ``w`` world, ``b`` hand base, ``o`` object, ``l`` link), SI units
(m, N, N*m, s, rad), and arrays rather than per-contact objects on the control path.
"""

from wholehand.errors import (
    AssetError,
    ConfigError,
    PluginError,
    WholehandError,
)

__version__ = "0.1.0"

__all__ = [
    "AssetError",
    "ConfigError",
    "PluginError",
    "WholehandError",
    "__version__",
]
