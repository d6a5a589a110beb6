"""The grasp file format: ``objects/grasps/<hand>/<object>.json`` for a shipped hand's power
grasps, ``objects/grasps/<hand>/<style>/<object>.json`` for another style of hand.toml's
``[grasping]`` (e.g. ``precision``); a user's hand keeps the same layout in the folder
``grasps/`` beside its hand.toml (:func:`hand_grasps_dir`).

A grasp is a hand base pose in the object frame plus joint angles by joint name, so that grasps
from any synthesiser (Dexonomy, DexGraspNet, ...) can be converted: express the hand root pose
in the object's mesh frame as a 4x4 matrix ``oMb`` and write one entry per joint::

    {
      "format": "wholehand-grasps/1",
      "hand": "allegro_right",
      "object": "077_rubiks_cube",
      "generator": {"command": "...", "seed": 0, ...},
      "grasps": [
        {"id": 0, "type": "power", "oMb": [[...], [...], [...], [0, 0, 0, 1]],
         "q": {"joint_0.0": 0.05, ...}, "contacts": 7, "note": "..."}
      ]
    }

Units: metres and radians. ``contacts`` (optional) is the ground-truth contact count after
settling, as the generator measured it.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from wholehand.errors import ConfigError
from wholehand.models.hand import HandModel
from wholehand.models.poses import check_pose, inverse

FloatArray = npt.NDArray[np.float64]
FORMAT = "wholehand-grasps/1"

LIMIT_SLACK = 0.05
"""How far past a joint limit a stored angle may lie [rad]: grasps settle in MuJoCo, whose
limits are soft (the shipped grasps lie at most 0.015 rad past theirs)."""


@dataclass(frozen=True)
class Grasp:
    """One stored grasp."""

    id: int
    oMb: FloatArray
    """(4, 4) pose of the hand base in the object frame."""
    q: dict[str, float]
    """Joint angles [rad] by joint name."""
    type: str = "power"
    contacts: int | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    source: str = ""
    """The file it was read from ("" if none), for errors."""

    def q_array(self, hand: HandModel) -> FloatArray:
        """(n_q,) joint angles in the hand model's order.

        Raises:
            ConfigError: a joint of the hand has no angle, or an angle lies more than
                :data:`LIMIT_SLACK` past its joint's limits (naming the file, grasp, joint,
                angle and limits).
        """
        where = f"{self.source}: grasp {self.id}" if self.source else f"grasp {self.id}"
        missing = [name for name in hand.joint_names if name not in self.q]
        if missing:
            raise ConfigError(f"{where} has no angle for joints {missing} of {hand.name!r}")
        q = np.zeros(hand.nq)
        for name in hand.joint_names:
            q[hand.model.joints[hand.model.getJointId(name)].idx_q] = self.q[name]
        problem = joint_past_limits(hand, q)
        if problem is not None:
            raise ConfigError(f"{where}: {problem} of {hand.name!r}; fix or remove the grasp")
        return q

    def object_pose(self, wMb: FloatArray) -> FloatArray:
        """(4, 4) object pose in the world for a hand base mounted at ``wMb``."""
        return wMb @ inverse(self.oMb)


def joint_past_limits(hand: HandModel, q: FloatArray) -> str | None:
    """The first of the hand's joints whose angle in ``q`` (n_q,) [rad] lies more than
    :data:`LIMIT_SLACK` past its limits, with that angle and the limits; None if none (such a
    grasp could not be stored: :meth:`Grasp.q_array` refuses it)."""
    for name in hand.joint_names:
        i = hand.model.joints[hand.model.getJointId(name)].idx_q
        lower, upper = hand.q_lower[i], hand.q_upper[i]
        if not lower - LIMIT_SLACK <= q[i] <= upper + LIMIT_SLACK:
            return (
                f"joint {name!r} at {q[i]:.4g} rad is outside its limits [{lower:.4g}, {upper:.4g}]"
            )
    return None


def grasps_dir() -> Path:
    """The folder of shipped grasp files."""
    import wholehand_objects

    return Path(wholehand_objects.__file__).parent / "grasps"


def hand_grasps_dir(hand: str | Path) -> Path:
    """Where a hand's grasp files live: ``objects/grasps/<name>/`` for a shipped hand, the
    folder ``grasps/`` beside the hand.toml of any other (a user's hand keeps its grasps with
    it, wherever it is and however its path is written)."""
    from wholehand.models.hand_folders import is_shipped_hand, resolve_hand_config

    folder = resolve_hand_config(hand).resolve().parent
    if is_shipped_hand(folder):
        return grasps_dir() / folder.name
    return folder / "grasps"


def grasp_file(hand: str | Path, obj: str, style: str = "power", on_table: bool = False) -> Path:
    """The file of a hand's grasps of an object: ``<object>.json`` for power grasps,
    ``<style>/<object>.json`` for another grasp style (e.g. ``precision``), in
    :func:`hand_grasps_dir`; grasps of the object resting on a table (``on_table``, made with
    ``wholehand grasps generate --on-table``) in a subfolder ``on_table/`` of those. ``hand`` is
    a shipped hand's name or a hand folder; ``obj`` an object's name or its mesh file's path,
    written any way (relative or absolute: the file's stem names the object, as
    :func:`~wholehand.models.object_catalogue.load_object` names it)."""
    return _style_dir(hand, style, on_table) / f"{object_key(obj)}.json"


def object_key(obj: str) -> str:
    """The name an object's grasps are filed under: a mesh path's file stem, a YCB name or a
    primitive spec as it is."""
    from wholehand.models.object_catalogue import MESH_SUFFIXES

    path = Path(obj)
    if "/" in obj or "\\" in obj or path.suffix.lower() in MESH_SUFFIXES:
        return path.stem
    return obj


def _style_dir(hand: str | Path, style: str, on_table: bool = False) -> Path:
    folder = hand_grasps_dir(hand)
    folder = folder if style == "power" else folder / style
    return folder / ON_TABLE if on_table else folder


ON_TABLE = "on_table"
"""Subfolder of a style's grasp files that holds its table-top grasps."""


def shipped_grasp_files() -> list[Path]:
    """Every shipped grasp file, sorted."""
    return sorted(grasps_dir().rglob("*.json"))


def objects_with_grasps(hand: str | Path, style: str = "power") -> list[str]:
    """Names of the objects that have a grasp file of ``hand`` and ``style``, sorted."""
    return sorted(p.stem for p in _style_dir(hand, style).glob("*.json"))


_GRASP_FOLDER: ContextVar[Path | None] = ContextVar("grasp_folder", default=None)


@contextmanager
def grasps_from(folder: str | Path) -> Iterator[None]:
    """Within the block, :func:`stored_grasp_indices` counts the grasps of
    ``folder/<object>.json`` (e.g. written by ``wholehand grasps generate --out folder``)
    instead of the hand's stored ones: a study expands its trials over a grasp folder's
    grasps, whether or not the hand has grasps of its own."""
    token = _GRASP_FOLDER.set(Path(folder))
    try:
        yield
    finally:
        _GRASP_FOLDER.reset(token)


def stored_grasp_indices(
    hand: str | Path, obj: str, style: str = "power", wanted: tuple[int, ...] | None = None
) -> list[int]:
    """Indices of the stored grasps of ``(hand, obj, style)`` among ``wanted`` (None: all);
    empty when there is no such file (inside :func:`grasps_from`, that folder's file of
    ``obj``)."""
    folder = _GRASP_FOLDER.get()
    path = grasp_file(hand, obj, style) if folder is None else folder / f"{object_key(obj)}.json"
    if not path.is_file():
        return []
    n = len(load_grasps(path))
    return [g for g in (range(n) if wanted is None else wanted) if g < n]


def _joint_angles(raw: Any, where: str) -> dict[str, float]:
    """``{"joint": angle}`` of a grasp entry; anything else is named."""
    if not isinstance(raw, dict):
        raise ConfigError(
            f'{where}: q must map joint names to angles [rad], e.g. {{"joint_0.0": 0.1}}; '
            f"got a {type(raw).__name__}"
        )
    out = {}
    for joint, value in raw.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
            raise ConfigError(f"{where}: q[{joint!r}] must be a finite angle [rad], got {value!r}")
        out[str(joint)] = float(value)
    return out


def _check_style(hand: str | Path, style: str) -> None:
    """Name a grasp style the hand has no grasps of when it is close to one it has (a typo)."""
    import difflib

    folder = hand_grasps_dir(hand)
    if not folder.is_dir():
        return
    styles = ["power", *(p.name for p in folder.iterdir() if p.is_dir() and p.name != "on_table")]
    if style in styles:
        return
    close = difflib.get_close_matches(style, styles, n=1, cutoff=0.75)
    if close:
        raise ConfigError(
            f"no grasp style {style!r} for this hand: did you mean {close[0]!r}? Its grasps "
            f"are of the styles {sorted(styles)}"
        )


def load_grasps(
    path_or_hand: str | Path, obj: str | None = None, style: str = "power", on_table: bool = False
) -> list[Grasp]:
    """Grasps from a file path, or the stored ones for ``(hand, object name, style,
    on_table)`` (a shipped hand's name or a hand folder, see :func:`grasp_file`)."""
    path = Path(path_or_hand) if obj is None else grasp_file(path_or_hand, obj, style, on_table)
    if not path.is_file():
        if obj is None:
            raise ConfigError(f"no grasp file {path}; check the path")
        _check_style(path_or_hand, style)
        stored = sorted(p.stem for p in path.parent.glob("*.json"))
        kind = f"{style} grasps{' on a table' if on_table else ''}"
        raise ConfigError(
            f"no grasp file {path}: {kind} of this hand exist for {stored or 'no object'}. "
            f"Generate some with `wholehand grasps generate --hand {path_or_hand} --object {obj}"
            f"{'' if style == 'power' else f' --type {style}'}{' --on-table' if on_table else ''}`"
        )
    try:
        raw = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ConfigError(f"{path}: not valid JSON: {err}") from err
    if raw.get("format") != FORMAT:
        raise ConfigError(f"{path}: format is {raw.get('format')!r}, expected {FORMAT!r}")
    grasps = []
    for i, entry in enumerate(raw.get("grasps", [])):
        try:
            oMb = check_pose(entry["oMb"], f"{path} grasp {i} oMb")
            q = _joint_angles(entry["q"], f"{path}: grasp {i}")
        except KeyError as err:
            raise ConfigError(f"{path}: grasp {i} lacks the key {err}") from err
        grasps.append(
            Grasp(
                id=int(entry.get("id", i)),
                oMb=oMb,
                q=q,
                type=str(entry.get("type", "power")),
                contacts=entry.get("contacts"),
                extra={
                    k: v
                    for k, v in entry.items()
                    if k not in {"id", "oMb", "q", "type", "contacts"}
                },
                source=str(path),
            )
        )
    if not grasps:
        raise ConfigError(f"{path}: holds no grasps")
    return grasps


def grasp_file_object(path: str | Path) -> str:
    """The object a grasp file holds grasps of (its ``object`` field)."""
    path = Path(path)
    try:
        raw = json.loads(path.read_text())
        return str(raw["object"])
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as err:
        raise ConfigError(
            f"{path}: cannot read the object of this grasp file ({err}); it must be a "
            f"{FORMAT} JSON file with an 'object' field"
        ) from err


def save_grasps(
    path: Path, hand: str, obj: str, grasps: list[Grasp], generator: dict[str, Any]
) -> Path:
    """Write grasps in the documented format."""
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": FORMAT,
        "hand": hand,
        "object": obj,
        "generator": generator,
        "grasps": [
            {
                "id": g.id,
                "type": g.type,
                "oMb": np.round(g.oMb, 9).tolist(),
                "q": {k: round(v, 9) for k, v in g.q.items()},
                "contacts": g.contacts,
                **g.extra,
            }
            for g in grasps
        ],
    }
    try:
        text = json.dumps(payload, indent=1, allow_nan=False)
    except ValueError:
        bad = [
            g.id
            for g in grasps
            if not (np.isfinite(g.oMb).all() and np.isfinite(list(g.q.values())).all())
        ]
        raise ConfigError(
            f"{path}: grasps {bad or '(their extra fields)'} hold a value that is not finite; "
            "a grasp file is strict JSON, nothing was written"
        ) from None
    path.write_text(text + "\n")
    return path
