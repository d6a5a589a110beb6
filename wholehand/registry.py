"""Plug-in registry over Python entry points.

Plug-ins are discovered in four entry-point groups (``wholehand.contact_estimators``,
``wholehand.allocators``, ``wholehand.reachers``, ``wholehand.backends``). wholehand's own
plug-ins are registered there by its ``pyproject.toml`` exactly as a third-party distribution
registers its own, and the core never imports a plug-in by module path.

Name clashes: when two distributions register the same name in one group, a warning is issued
and the built-in one (from the ``wholehand`` distribution) wins; between two third-party
distributions the one whose distribution name sorts first wins. Either can still be reached
under the qualified name ``"<distribution>:<name>"``.
"""

from __future__ import annotations

import functools
import inspect
import warnings
from dataclasses import dataclass
from importlib import metadata
from typing import Any, cast

from wholehand.errors import PluginError, WholehandError

GROUPS: dict[str, str] = {
    "contact_estimators": "wholehand.contact_estimators",
    "allocators": "wholehand.allocators",
    "reachers": "wholehand.reachers",
    "backends": "wholehand.backends",
}
"""Short group name -> entry-point group."""

BUILTIN_DISTRIBUTION = "wholehand"


@dataclass(frozen=True)
class PluginSpec:
    """One registered plug-in, not yet imported."""

    group: str
    """Short group name, e.g. ``"allocators"``."""
    name: str
    """Name the plug-in is loaded by."""
    value: str
    """Entry-point target ``module:attribute``."""
    distribution: str
    """Name of the distribution that registered it."""
    entry_point: metadata.EntryPoint

    @property
    def builtin(self) -> bool:
        return self.distribution == BUILTIN_DISTRIBUTION

    def load(self) -> type:
        """Import the plug-in class; an import failure raises :class:`PluginError`."""
        try:
            return cast(type, self.entry_point.load())
        except Exception as err:
            raise PluginError(
                f"plug-in {self.name!r} in group {GROUPS[self.group]!r} (entry point "
                f"{self.value!r} of distribution {self.distribution!r}) failed to import: "
                f"{type(err).__name__}: {err}. Reinstall {self.distribution!r} or fix the module."
            ) from err

    def description(self) -> str:
        """First line of the plug-in's docstring, or why it could not be read."""
        try:
            doc = self.load().__doc__ or ""
        except PluginError as err:
            return f"[cannot import: {err.__cause__}]"
        return doc.strip().splitlines()[0] if doc.strip() else ""


def _group_key(group: str) -> str:
    if group in GROUPS:
        return group
    for short, full in GROUPS.items():
        if group == full:
            return short
    raise PluginError(f"unknown plug-in group {group!r}; the groups are {sorted(GROUPS)}")


@functools.cache
def _discover() -> dict[str, dict[str, PluginSpec]]:
    found: dict[str, dict[str, PluginSpec]] = {g: {} for g in GROUPS}
    qualified: dict[str, dict[str, PluginSpec]] = {g: {} for g in GROUPS}
    for short, full in GROUPS.items():
        specs = []
        for ep in metadata.entry_points(group=full):
            dist = ep.dist.name if ep.dist is not None else "<unknown>"
            specs.append(PluginSpec(short, ep.name, ep.value, dist, ep))
        # Built-ins first, then third-party distributions in name order: the first one wins.
        specs.sort(key=lambda s: (not s.builtin, s.distribution.lower(), s.name))
        for spec in specs:
            qualified[short][f"{spec.distribution}:{spec.name}"] = spec
            winner = found[short].get(spec.name)
            if winner is None:
                found[short][spec.name] = spec
            elif winner.value != spec.value or winner.distribution != spec.distribution:
                warnings.warn(
                    f"plug-in name {spec.name!r} in group {full!r} is registered by both "
                    f"{winner.distribution!r} ({winner.value}) and {spec.distribution!r} "
                    f"({spec.value}); using the one from {winner.distribution!r}. Load the other "
                    f"as {spec.distribution + ':' + spec.name!r}.",
                    stacklevel=3,
                )
    return {g: {**found[g], **qualified[g]} for g in GROUPS}


def refresh() -> None:
    """Forget discovered plug-ins; the next lookup reads the entry points again."""
    _discover.cache_clear()


def available(group: str) -> dict[str, PluginSpec]:
    """Plug-ins of a group by their plain names (qualified aliases left out)."""
    specs = _discover()[_group_key(group)]
    return {name: spec for name, spec in sorted(specs.items()) if ":" not in name}


def get_class(group: str, name: str | type) -> type:
    """The plug-in class registered under ``name`` (a class is returned as it is)."""
    if isinstance(name, type):
        return name
    key = _group_key(group)
    specs = _discover()[key]
    if name not in specs:
        names = ", ".join(available(key)) or "(none installed)"
        raise PluginError(
            f"no plug-in named {name!r} in group {GROUPS[key]!r}; installed: {names}. "
            "Check the spelling or install the distribution that provides it."
        )
    return specs[name].load()


def load(group: str, name: str | type, /, **params: Any) -> Any:
    """Construct the plug-in ``name`` of ``group`` with keyword parameters."""
    cls = get_class(group, name)
    try:
        inspect.signature(cls).bind(**params)
    except TypeError as err:
        raise PluginError(
            f"plug-in {name!r} of group {GROUPS[_group_key(group)]!r} rejected its parameters "
            f"{sorted(params)}: {err}"
        ) from err
    try:
        return cls(**params)
    except WholehandError:
        raise  # already names the problem and the fix
    except Exception as err:
        raise PluginError(
            f"plug-in {name!r} of group {GROUPS[_group_key(group)]!r} ({cls.__module__}."
            f"{cls.__qualname__}) raised while it was constructed with {sorted(params)}: "
            f"{type(err).__name__}: {err}; fix the plug-in or its parameters"
        ) from err
