"""Replay a :class:`~wholehand.loop.record.RunRecord` live in meshcat or as standalone HTML.

The HTML is a meshcat ``Animation`` of every node pose, played in sim time, with meshcat's viewer
JavaScript inlined, so it opens from disk in a browser with no server and no network. The hand's
distance colouring in the HTML is a still: the colours of the frame with the most contacts.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pinocchio as pin
from meshcat.animation import Animation, AnimationClip

from wholehand.loop.record import RunRecord
from wholehand.models.hand import HandModel
from wholehand.models.objects import ObjectModel
from wholehand.viz.arrows import force_arrows
from wholehand.viz.colours import ColourScale
from wholehand.viz.scene import NodePose, SceneViewer

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

REPLAY_FPS = 20.0
"""Frames per second of sim time in a recorded animation."""


def load_models(record: RunRecord) -> tuple[HandModel, ObjectModel]:
    """The hand and object named in the record's spec."""
    from wholehand.models.hand import load_hand
    from wholehand.models.object_catalogue import load_object

    spec = record.meta.get("spec") or {}
    return load_hand(spec.get("hand", "allegro_right")), load_object(
        spec.get("object", "077_rubiks_cube")
    )


def object_pose(record: RunRecord, cycle: int) -> FloatArray:
    """(4, 4) object pose in the world at one cycle."""
    a = record.rows
    M = np.eye(4)
    M[:3, :3] = pin.exp3(np.asarray(a["r_object"][cycle], dtype=float))
    M[:3, 3] = np.asarray(a["p_object"][cycle], dtype=float)
    return M


def base_pose(record: RunRecord, cycle: int) -> FloatArray | None:
    """(4, 4) hand base pose at one cycle; None for records without it (base at its mount)."""
    a = record.rows
    if not a.get("p_base"):
        return None
    M = np.eye(4)
    M[:3, :3] = pin.exp3(np.asarray(a["r_base"][cycle], dtype=float))
    M[:3, 3] = np.asarray(a["p_base"][cycle], dtype=float)
    return M


def frame_cycles(record: RunRecord, fps: float = REPLAY_FPS) -> IntArray:
    """Cycles shown at ``fps`` frames per second of sim time (first and last always included)."""
    t = np.asarray(record.rows.get("t", []), dtype=float)
    if t.size == 0:
        return np.zeros(0, dtype=np.intp)
    wanted = np.arange(t[0], t[-1] + 1e-9, 1.0 / fps)
    cycles = np.unique(np.r_[np.searchsorted(t, wanted).clip(0, t.size - 1), t.size - 1])
    return cycles.astype(np.intp)


FRAMING_SAMPLES = 12
"""Cycles of a record whose hand poses the camera frames."""


def record_scene_points(record: RunRecord, hand: HandModel, obj: ObjectModel) -> FloatArray:
    """Points (N, 3) a camera must show to see the whole record: the hand at
    :data:`FRAMING_SAMPLES` cycles spread over it and the object along its path
    (:func:`~wholehand.viz.scene.scene_points`)."""
    from wholehand.viz.scene import scene_points

    n = len(record.rows.get("t", []))
    if n == 0:
        return np.zeros((0, 3))
    cycles = np.unique(np.linspace(0, n - 1, min(n, FRAMING_SAMPLES)).astype(int))
    states = [
        (np.asarray(record.rows["q"][i], dtype=float), base_pose(record, int(i))) for i in cycles
    ]
    radius = 0.5 * float(np.linalg.norm(obj.mesh.extents))
    path = np.asarray(record.rows["p_object"], dtype=float)[:: max(1, n // 200)]
    return scene_points(hand, states, [(p, radius) for p in path])


def record_colour_scale(record: RunRecord, min_force: float) -> ColourScale:
    """A force colour scale covering every commanded force of the record."""
    forces = record.rows.get("contact_f", [])
    mags = (
        np.concatenate([np.linalg.norm(np.asarray(f).reshape(-1, 3), axis=1) for f in forces])
        if forces
        else np.zeros(0)
    )
    return ColourScale.for_forces(mags, f_min=min_force)


def _reserve(viewer: SceneViewer, record: RunRecord, cycles: IntArray) -> None:
    n_contacts = 0
    per_bin: dict[int, int] = {}
    for i in cycles:
        c = record.contacts_at(int(i))
        n_contacts = max(n_contacts, len(c["contact_p"]))
        arrows = force_arrows(c["contact_p"], c["contact_f"], viewer.min_force)
        for b, n in zip(
            *np.unique(viewer.colour_scale.bin(arrows.magnitude), return_counts=True), strict=True
        ):
            per_bin[int(b)] = max(per_bin.get(int(b), 0), int(n))
    viewer.reserve(n_contacts, per_bin)


def _append(clip: AnimationClip, frame: int, pose: NodePose) -> None:
    """Add a key per property, skipping a value equal to the previous two (linear interpolation
    between equal keys is exact, so runs of equal values need only their ends)."""
    for prop, jstype, value in (
        ("position", "vector3", list(pose.position)),
        ("quaternion", "quaternion", list(pose.quaternion)),
        ("scale", "vector3", list(pose.scale)),
    ):
        track = clip.tracks.get(prop)
        if (
            track is not None
            and len(track.values) >= 2
            and track.values[-1] == value == track.values[-2]
        ):
            track.frames[-1] = frame  # extend the run
            continue
        clip.set_property(frame, prop, jstype, value)


def build_animation(viewer: SceneViewer, record: RunRecord, fps: float = REPLAY_FPS) -> Animation:
    """Animate every node of ``viewer`` through the record (``fps`` frames per s of sim time)."""
    cycles = frame_cycles(record, fps)
    _reserve(viewer, record, cycles)
    animation = Animation(default_framerate=fps)
    clips: dict[str, AnimationClip] = {}
    q = record.rows["q"]
    for frame, i in enumerate(cycles):
        c = record.contacts_at(int(i))
        poses = viewer.poses(
            q[int(i)],
            object_pose(record, int(i)),
            c["contact_p"],
            c["contact_f"],
            base_pose(record, int(i)),
        )
        for path, pose in poses.items():
            clip = clips.get(path)
            if clip is None:
                clip = clips[path] = AnimationClip(fps=fps)
                animation.clips[viewer.vis[path].path] = clip
            _append(clip, frame, pose)
    return animation


def busiest_cycle(record: RunRecord) -> int:
    """The cycle with the most contacts (the first of them)."""
    n = np.asarray(record.rows.get("n_contacts", [0]))
    return int(np.argmax(n)) if n.size else 0


def write_html(
    record: RunRecord,
    path: str | Path,
    hand: HandModel | None = None,
    obj: ObjectModel | None = None,
    fps: float = REPLAY_FPS,
    distance_colours: bool = False,
    min_force: float | None = None,
    loop: bool = True,
) -> Path:
    """Write the record as a standalone HTML animation (opens offline); returns the path."""
    from wholehand.viz.arrows import FORCE_ARROW_MIN_N

    if hand is None or obj is None:
        loaded = load_models(record)
        hand, obj = hand or loaded[0], obj or loaded[1]
    threshold = FORCE_ARROW_MIN_N if min_force is None else float(min_force)
    viewer = SceneViewer.offline(
        hand,
        obj,
        colour_scale=record_colour_scale(record, threshold),
        min_force=threshold,
        distance_colours=distance_colours,
        legend=False,
    )
    if record.meta.get("table"):
        from wholehand.backends.table import Table

        viewer.draw_table(Table(**record.meta["table"]))
    if record.rows.get("t"):
        viewer.frame(record_scene_points(record, hand, obj))
        if distance_colours:
            i = busiest_cycle(record)
            c = record.contacts_at(i)
            viewer.poses(
                record.rows["q"][i], object_pose(record, i), c["contact_p"], c["contact_f"]
            )
            viewer.colour_distances(c["contact_p"])
        viewer.vis.set_animation(
            build_animation(viewer, record, fps), play=True, repetitions=10**6 if loop else 1
        )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(viewer.static_html(), encoding="utf-8")
    return path


def replay_live(
    record: RunRecord,
    viewer: SceneViewer,
    speed: float = 1.0,
    fps: float = REPLAY_FPS,
) -> None:
    """Play the record in a live viewer at ``speed`` times sim time."""
    t = np.asarray(record.rows["t"], dtype=float)
    start = time.perf_counter()
    for i in frame_cycles(record, fps):
        c = record.contacts_at(int(i))
        viewer.update(
            record.rows["q"][int(i)],
            object_pose(record, int(i)),
            c["contact_p"],
            c["contact_f"],
            base_pose(record, int(i)),
        )
        wait = (t[i] - t[0]) / speed - (time.perf_counter() - start)
        if wait > 0:
            time.sleep(wait)
