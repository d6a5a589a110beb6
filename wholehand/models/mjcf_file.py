"""The MJCF file that Pinocchio and the MuJoCo scene read for an MJCF hand.

Pinocchio's MJCF parser reads one self-contained file whose first root body is the robot: it does
not follow ``<include>`` (a model split over files, as registry packages ship them, parses as an
empty model) and stops at the first root body of a scene file (a floor body before the hand). A
hand that is a plain single-body file is read as it is. Otherwise MuJoCo loads it (includes,
defaults and all), the bodies beside ``root_body`` are removed, mesh and texture folders are made
absolute, and the result is written once under its content hash in the cache folder.

MuJoCo writes numbers with 6 significant digits and orientations as quaternions, so a written
file places its bodies to about 1e-6 of the original; a plain file is not rewritten.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco

from wholehand.errors import AssetError, ConfigError
from wholehand.models.cache import text_file

if TYPE_CHECKING:
    from wholehand.models.hand_config import HandConfig

_INCLUDE = re.compile(rb"<\s*include\b")


def mjcf_for_parsers(cfg: HandConfig) -> Path:
    """The MJCF file of ``cfg`` as Pinocchio and the scene builder read it: the file itself,
    or its self-contained copy (module docstring).

    Raises:
        AssetError: MuJoCo cannot load the file.
        ConfigError: ``root_body`` is not a root body of the file, or the file has several
            root bodies and no ``root_body`` says which is the hand.
    """
    path = cfg.model_path
    if cfg.root_body is None and not _INCLUDE.search(path.read_bytes()):
        return path
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except ValueError as err:
        raise AssetError(f"{path}: MuJoCo cannot load this MJCF: {err}") from err
    roots = [body.name for body in spec.worldbody.bodies]
    keep = cfg.root_body
    if keep is None:
        if len(roots) != 1:
            raise ConfigError(
                f"{cfg.path}: {path.name} has {len(roots)} root bodies {roots}; name the hand's "
                'with root_body = "..." in hand.toml'
            )
    elif keep not in roots:
        raise ConfigError(
            f"{cfg.path}: root_body = {keep!r} is not a root body of {path.name}; its root "
            f"bodies are {roots}"
        )
    if keep is not None:
        for body in list(spec.worldbody.bodies):
            if body.name != keep:
                spec.delete(body)
    folder = path.parent
    spec.meshdir = str((folder / spec.meshdir).resolve())
    spec.texturedir = str((folder / spec.texturedir).resolve())
    return text_file("mjcf", path.stem, spec.to_xml(), "xml")
