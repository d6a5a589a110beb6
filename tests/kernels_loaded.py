"""Which compiled kernels wholehand has loaded, for tests that no control cycle loads one.

Each argument type of a numba kernel (an array's dtype, dimensions, layout, writability) is a
machine-code version of its own, loaded on its first call: milliseconds, from the cache or a
compile. Loading them is the constructors' job; a cycle that meets a new version pays it.
"""

from __future__ import annotations

import sys

import numba


def kernel_versions() -> dict[str, set[str]]:
    """Every numba kernel of wholehand and its plug-ins, by qualified name, with the argument
    types of each version loaded so far."""
    out: dict[str, set[str]] = {}
    for name, module in list(sys.modules.items()):
        if not name.startswith("wholehand"):
            continue
        for attr, value in list(vars(module).items()):
            if isinstance(value, numba.core.registry.CPUDispatcher):
                out[f"{name}.{attr}"] = {str(sig) for sig in value.signatures}
    return out


def loaded_since(before: dict[str, set[str]]) -> dict[str, set[str]]:
    """The kernel versions loaded since ``before`` (:func:`kernel_versions`)."""
    now = kernel_versions()
    new = {name: sigs - before.get(name, set()) for name, sigs in now.items()}
    return {name: sigs for name, sigs in new.items() if sigs}
