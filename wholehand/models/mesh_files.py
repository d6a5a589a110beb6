"""Mesh files a URDF names: ``package://``, ``file://`` and relative URIs resolved, missing ones
named with every folder searched."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from urllib.parse import unquote, urlparse

from wholehand.errors import AssetError


def _mesh_uris(model_path: Path, surface: str) -> list[str]:
    root = ET.parse(model_path).getroot()
    return [
        m.get("filename", "")
        for link in root.iter("link")
        for elem in link.iter(surface)
        for m in elem.iter("mesh")
    ]


def resolve_mesh_uri(uri: str, model_path: Path, package_dirs: tuple[Path, ...]) -> Path | None:
    """The file a URDF mesh URI names (``package://``, ``file://`` or relative), None if absent."""
    if uri.startswith("package://"):
        rel = uri[len("package://") :]
        for d in package_dirs:
            if (d / rel).is_file():
                return d / rel
        return None
    if uri.startswith("file://"):
        path = Path(unquote(urlparse(uri).path))
    else:
        path = model_path.parent / uri
    return path if path.is_file() else None


def check_meshes(urdf: Path, package_dirs: tuple[Path, ...], surface: str) -> list[Path]:
    """The mesh files of the URDF's ``surface`` geometry (``collision`` or ``visual``), found
    beside it or in ``package_dirs``; a missing one raises AssetError naming every folder
    searched. (An MJCF's meshes are found by Pinocchio's parser.)"""
    found = []
    for uri in _mesh_uris(urdf, surface):
        path = resolve_mesh_uri(uri, urdf, package_dirs)
        if path is None:
            dirs = "\n  ".join(str(d) for d in package_dirs)
            raise AssetError(
                f"{urdf}: {surface} mesh {uri!r} not found. Searched relative to the "
                f"URDF and in the package directories:\n  {dirs}\nInstall the package that ships "
                "it or fix the filename in the URDF."
            )
        found.append(path)
    return found
