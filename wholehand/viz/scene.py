"""A meshcat scene of a hand holding an object: link meshes, contacts and force arrows.

The scene follows Fig. 1 of the paper: arrows show the commanded contact forces of at least
:data:`FORCE_ARROW_MIN_N` at the detected contact points, coloured by magnitude (a discrete
colour scale with a legend), and the hand's surface samples can be coloured by their distance to
the nearest contact.

Scene tree (meshcat paths)::

    /wholehand/hand/<joint>            one group per Pinocchio joint, pose wMb @ bMj
    /wholehand/hand/<joint>/<geometry> the link's visual mesh, fixed placement in the joint frame
    /wholehand/hand/<joint>/samples    surface samples (point cloud; distance colouring)
    /wholehand/object                  object mesh, pose wMo
    /wholehand/contacts/<k>            contact point spheres (a pool; unused ones shrunk away)
    /wholehand/forces/<bin>/<k>        force arrows of colour bin <bin> (a pool per bin)
    /wholehand/legend                  colour bar as a textured slab (live viewer)

Every node pose is a :class:`NodePose` (position, quaternion, scale), so the same poses drive a
live viewer (:meth:`SceneViewer.update`) and a recorded animation (:mod:`wholehand.viz.replay`).
An arrow of length L is a unit arrow along +y scaled by (1, L, 1); a hidden pool member is
scaled by :data:`HIDDEN_SCALE`.
"""

from __future__ import annotations

import base64
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple, cast

import meshcat
import meshcat.geometry as mg
import numpy as np
import numpy.typing as npt
import pinocchio as pin
import trimesh

from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel
from wholehand.viz.arrows import FORCE_ARROW_MIN_N, force_arrows, y_to
from wholehand.viz.colours import ColourScale, distance_rgb, distance_to_nearest_contact
from wholehand.viz.recording import RecordingWindow

if TYPE_CHECKING:
    from wholehand.backends.table import Table

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

ARROW_RADIUS_M = 0.0015
"""Shaft radius of a force arrow [m]."""
CONTACT_RADIUS_M = 0.002
"""Radius of a contact-point sphere [m]."""
HAND_RGB = (0.25, 0.25, 0.28)
"""Hand colour where the URDF gives none."""
OBJECT_RGB = (0.2, 0.75, 0.7)
"""Object colour (teal, away from the force colour map)."""
TABLE_RGB = (0.55, 0.45, 0.35)
"""Colour of a table."""
OBJECT_OPACITY = 0.55
BACKGROUND_RGB = (1.0, 1.0, 1.0)
HIDDEN_SCALE = 1e-6
"""Scale of a pool member that shows nothing this frame."""
ROOT = "wholehand"


class NodePose(NamedTuple):
    """Pose of one scene node in its parent (the world for every animated node)."""

    position: tuple[float, float, float]
    """(3,) translation [m]."""
    quaternion: tuple[float, float, float, float]
    """(4,) rotation as (x, y, z, w) (three.js order)."""
    scale: tuple[float, float, float]
    """(3,) scale along the node's own axes."""

    @classmethod
    def from_matrix(
        cls, M: FloatArray, scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    ) -> NodePose:
        """From a (4, 4) rigid transform (no scale in it) and a separate scale."""
        quat = pin.Quaternion(np.asarray(M[:3, :3], dtype=float)).coeffs()  # (x, y, z, w)
        return cls(
            tuple(float(v) for v in M[:3, 3]),  # type: ignore[arg-type]
            tuple(float(v) for v in quat),  # type: ignore[arg-type]
            tuple(float(s) for s in scale),  # type: ignore[arg-type]
        )

    def matrix(self) -> FloatArray:
        """(4, 4) transform with the scale applied after the rotation's columns."""
        x, y, z, w = self.quaternion
        M = np.eye(4)
        M[:3, :3] = pin.Quaternion(w, x, y, z).toRotationMatrix() * np.asarray(self.scale)
        M[:3, 3] = self.position
        return M


HIDDEN = NodePose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), (HIDDEN_SCALE,) * 3)


# --- the viewer -----------------------------------------------------------------------------------
@dataclass
class _Pools:
    contacts: int = 0
    arrows: dict[int, int] = field(default_factory=dict)


class SceneViewer:
    """A hand and an object in meshcat, updated from joint positions, poses and contacts.

    Build one with :meth:`live` (starts meshcat's local server, prints its URL; no network
    needed) or :meth:`offline` (records into a :class:`RecordingWindow` for HTML), or pass any
    :class:`meshcat.Visualizer`.

    Args:
        hand: the hand model (visual meshes, surface samples, mount pose).
        obj: the object model (mesh in the object frame).
        vis: the meshcat visualizer to draw into.
        colour_scale: force colour scale (default: 0.5 N to 5 N in 8 colours).
        min_force: smallest force drawn as an arrow [N].
        distance_colours: show the hand's surface samples coloured by distance to the nearest
            contact (toggle later with :meth:`set_distance_colours`).
        legend: draw the colour bar as a textured slab beside the hand.
    """

    def __init__(
        self,
        hand: HandModel,
        obj: ObjectModel,
        vis: meshcat.Visualizer,
        colour_scale: ColourScale | None = None,
        min_force: float = FORCE_ARROW_MIN_N,
        distance_colours: bool = False,
        legend: bool = True,
    ) -> None:
        self.hand = hand
        self.obj = obj
        self.vis = vis
        self.colour_scale = colour_scale or ColourScale(f_min=min_force)
        self.min_force = float(min_force)
        self.kinematics = HandKinematics(hand)
        self.distance_colours = bool(distance_colours)
        self._pools = _Pools()
        self._bin_rgb = self.colour_scale.bin_rgb()
        self._joints = sorted(
            {int(g.parentJoint) for g in hand.visual_model.geometryObjects}
            | set(int(j) for j in np.unique(hand.samples.joint))
        )
        self._joint_path = {j: f"{ROOT}/hand/{hand.model.names[j]}" for j in self._joints}
        self.last_contact_p = np.zeros((0, 3))
        self._draw_static(legend)

    # --- construction ----------------------------------------------------------------------------
    @classmethod
    def live(
        cls, hand: HandModel, obj: ObjectModel, zmq_url: str | None = None, **kwargs: Any
    ) -> SceneViewer:
        """Start meshcat's local server (or use ``zmq_url``), print its URL, build the scene."""
        vis = meshcat.Visualizer(zmq_url=zmq_url)
        print(f"meshcat viewer: {vis.url()}", flush=True)
        return cls(hand, obj, vis, **kwargs)

    @classmethod
    def offline(cls, hand: HandModel, obj: ObjectModel, **kwargs: Any) -> SceneViewer:
        """A viewer with no server that records the scene for :meth:`static_html`."""
        return cls(hand, obj, meshcat.Visualizer(window=RecordingWindow()), **kwargs)

    @property
    def url(self) -> str | None:
        """The live viewer's web URL (None for an offline viewer)."""
        return getattr(self.vis.window, "web_url", None)

    def _draw_static(self, legend: bool) -> None:
        vis = self.vis
        vis["/Background"].set_property("top_color", list(BACKGROUND_RGB))
        vis["/Background"].set_property("bottom_color", list(BACKGROUND_RGB))
        vis["/Grid"].set_property("visible", False)
        vis["/Axes"].set_property("visible", False)
        vis[ROOT].delete()
        for geom in self.hand.visual_model.geometryObjects:
            mesh = _visual_mesh(geom)
            if mesh is None:
                continue
            rgba = np.asarray(geom.meshColor, dtype=float)
            colour = HAND_RGB if not np.any(rgba[:3]) else tuple(rgba[:3])
            material = mg.MeshLambertMaterial(color=_hex(colour))
            node = vis[f"{self._joint_path[int(geom.parentJoint)]}/{geom.name}"]
            node.set_object(mg.TriangularMeshGeometry(mesh.vertices, mesh.faces), material)
            node.set_transform(geom.placement.homogeneous)
        self._draw_samples(np.full(len(self.hand.samples), np.inf))
        node = vis[f"{ROOT}/object"]
        node.set_object(
            mg.TriangularMeshGeometry(self.obj.mesh.vertices, self.obj.mesh.faces),
            mg.MeshLambertMaterial(color=_hex(OBJECT_RGB), opacity=OBJECT_OPACITY),
        )
        if legend:
            self._draw_legend()

    def draw_table(self, table: Table) -> None:
        """Draw a table (:class:`~wholehand.backends.table.Table`), world frame."""
        node = self.vis[f"{ROOT}/table"]
        node.set_object(
            mg.Box((2.0 * table.half_extents).tolist()),
            mg.MeshLambertMaterial(color=_hex(TABLE_RGB)),
        )
        M = np.eye(4)
        M[:3, 3] = table.box_centre
        node.set_transform(M)

    def _draw_legend(self) -> None:
        png = self.colour_scale.legend_png()
        texture = mg.ImageTexture(mg.PngImage(png))
        node = self.vis[f"{ROOT}/legend"]
        node.set_object(mg.Box([0.05, 0.0005, 0.0929]), mg.MeshBasicMaterial(map=texture))
        M = np.eye(4)
        M[:3, 3] = self.hand.wMb[:3, 3] + np.array([0.0, 0.15, 0.1])
        node.set_transform(M)

    def _draw_samples(self, distance: FloatArray) -> None:
        """Surface samples per joint, coloured by distance; shown when distance colouring is on."""
        s = self.hand.samples
        rgb = distance_rgb(distance)
        for j in np.unique(s.joint):
            rows = s.joint == j
            node = self.vis[f"{self._joint_path[int(j)]}/samples"]
            node.set_object(
                mg.Points(
                    mg.PointsGeometry(
                        s.p_joint[rows].T.astype(np.float32), rgb[rows].T.astype(np.float32)
                    ),
                    mg.PointsMaterial(size=0.002),
                )
            )
            node.set_property("visible", self.distance_colours)

    def set_distance_colours(self, on: bool) -> None:
        """Toggle the hand's surface samples coloured by distance to the nearest contact."""
        self.distance_colours = bool(on)
        if on:
            self.colour_distances(self.last_contact_p)
        else:
            for j in np.unique(self.hand.samples.joint):
                self.vis[f"{self._joint_path[int(j)]}/samples"].set_property("visible", False)

    def colour_distances(self, contact_p: FloatArray) -> FloatArray:
        """Recolour the samples by distance to the contacts at the current pose.

        Returns:
            (P,) distance of each sample to its nearest contact [m].
        """
        s = self.hand.samples
        d = distance_to_nearest_contact(
            self.kinematics.transform_points(s.p_joint, s.joint), contact_p
        )
        self._draw_samples(d)
        return d

    # --- per cycle -------------------------------------------------------------------------------
    def reserve(self, n_contacts: int, arrows_per_bin: dict[int, int]) -> None:
        """Create pool members up front (an animation needs all its nodes from frame 0)."""
        self._grow_contacts(n_contacts)
        for b, n in arrows_per_bin.items():
            self._grow_arrows(int(b), int(n))

    def _grow_contacts(self, n: int) -> None:
        for k in range(self._pools.contacts, n):
            node = self.vis[f"{ROOT}/contacts/{k}"]
            node.set_object(mg.Sphere(CONTACT_RADIUS_M), mg.MeshBasicMaterial(color=0x111111))
            node.set_transform(HIDDEN.matrix())
        self._pools.contacts = max(self._pools.contacts, n)

    def _grow_arrows(self, b: int, n: int) -> None:
        have = self._pools.arrows.get(b, 0)
        # Unlit, drawn last and over everything: the colour on screen is the legend's colour
        # and arrows stay visible inside the translucent object and behind fingers.
        material = mg.MeshBasicMaterial(
            color=_hex(self._bin_rgb[b]), transparent=True, depthTest=False, depthWrite=False
        )
        head = 0.3
        for k in range(have, n):
            path = f"{ROOT}/forces/{b}/{k}"
            shaft = np.eye(4)
            shaft[1, 3] = (1.0 - head) / 2
            self.vis[f"{path}/shaft"].set_object(
                _OnTop(mg.Cylinder(1.0 - head, ARROW_RADIUS_M), material)
            )
            self.vis[f"{path}/shaft"].set_transform(shaft)
            tip = np.eye(4)
            tip[1, 3] = 1.0 - head / 2
            self.vis[f"{path}/head"].set_object(
                _OnTop(
                    mg.Cylinder(head, radiusTop=0.0, radiusBottom=2.5 * ARROW_RADIUS_M), material
                )
            )
            self.vis[f"{path}/head"].set_transform(tip)
            self.vis[path].set_transform(HIDDEN.matrix())
        self._pools.arrows[b] = max(have, n)

    def poses(
        self,
        q: npt.ArrayLike,
        wMo: FloatArray,
        contact_p: npt.ArrayLike,
        contact_f: npt.ArrayLike,
        wMb: FloatArray | None = None,
    ) -> dict[str, NodePose]:
        """Pose of every animated node for one cycle (grows the pools as needed).

        Args:
            q: (n_q,) joint positions.
            wMo: (4, 4) object pose in the world.
            contact_p: (M, 3) contact points, world frame [m].
            contact_f: (M, 3) commanded forces on the object, world frame [N].
            wMb: (4, 4) hand base pose (default: the hand's mount pose).
        """
        self.kinematics.update(q, self.hand.wMb if wMb is None else wMb)
        R, t = self.kinematics.joint_poses_in(np.eye(4))
        out: dict[str, NodePose] = {}
        for j in self._joints:
            M = np.eye(4)
            M[:3, :3], M[:3, 3] = R[j], t[j]
            out[self._joint_path[j]] = NodePose.from_matrix(M)
        out[f"{ROOT}/object"] = NodePose.from_matrix(np.asarray(wMo, dtype=float))
        p = np.asarray(contact_p, dtype=float).reshape(-1, 3)
        self.last_contact_p = p
        self._grow_contacts(len(p))
        for k in range(self._pools.contacts):
            out[f"{ROOT}/contacts/{k}"] = (
                NodePose(tuple(p[k]), (0.0, 0.0, 0.0, 1.0), (1.0, 1.0, 1.0))
                if k < len(p)
                else HIDDEN
            )
        arrows = force_arrows(p, contact_f, self.min_force)
        bins = self.colour_scale.bin(arrows.magnitude)
        for b in range(self.colour_scale.n_bins):
            rows = np.flatnonzero(bins == b)
            self._grow_arrows(b, len(rows))
            for k in range(self._pools.arrows.get(b, 0)):
                path = f"{ROOT}/forces/{b}/{k}"
                if k >= len(rows):
                    out[path] = HIDDEN
                    continue
                i = rows[k]
                M = np.eye(4)
                M[:3, :3] = y_to(arrows.direction[i])
                M[:3, 3] = arrows.tip[i] - arrows.length[i] * arrows.direction[i]
                out[path] = NodePose.from_matrix(M, (1.0, float(arrows.length[i]), 1.0))
        return out

    def update(
        self,
        q: npt.ArrayLike,
        wMo: FloatArray,
        contact_p: npt.ArrayLike,
        contact_f: npt.ArrayLike,
        wMb: FloatArray | None = None,
    ) -> None:
        """Draw one cycle (see :meth:`poses` for the arguments)."""
        for path, pose in self.poses(q, wMo, contact_p, contact_f, wMb).items():
            self.vis[path].set_transform(pose.matrix())
        if self.distance_colours:
            self.colour_distances(self.last_contact_p)

    def frame(self, points: npt.ArrayLike) -> None:
        """Point the camera at a scene spanning ``points`` (N, 3) [m, world] so that all of
        it is in view (:func:`framing`)."""
        self.set_camera(*framing(points))

    def set_camera(
        self, target: FloatArray, offset: tuple[float, float, float] = (0.16, 0.1, 0.13)
    ) -> None:
        """Orbit the camera about ``target`` (3,) [m], from ``offset`` (world x, y, z) [m]."""
        M = np.eye(4)
        M[:3, 3] = np.asarray(target, dtype=float)
        self.vis["/Cameras/default"].set_transform(M)
        x, y, z = offset  # the camera's "rotated" frame is y-up
        self.vis["/Cameras/default/rotated/<object>"].set_property("position", [x, z, -y])

    def legend_overlay_html(self) -> str:
        """The colour bar as an HTML block (for standalone pages)."""
        data = base64.b64encode(self.colour_scale.legend_png()).decode("ascii")
        img = f'<img src="data:image/png;base64,{data}" alt="force colour bar">'
        return f'<div id="wholehand-overlay">{img}</div>'

    def static_html(self, overlay: bool = True) -> str:
        """Standalone HTML of the recorded scene (offline viewers only)."""
        window = self.vis.window
        if not isinstance(window, RecordingWindow):
            return self.vis.static_html()
        return window.get_scene(self.legend_overlay_html() if overlay else "")


CAMERA_FOV_DEG = 75.0
"""Vertical field of view of meshcat's default camera [deg]."""
VIEW_DIRECTION = np.array([0.16, 0.1, 0.13]) / np.linalg.norm([0.16, 0.1, 0.13])
"""From the scene's centre towards the camera: in front, to the side and above (world)."""


def framing(
    points: npt.ArrayLike, min_radius: float = 0.08, margin: float = 1.15
) -> tuple[FloatArray, tuple[float, float, float]]:
    """Camera target (3,) and offset (world) [m] that show every one of ``points`` (N, 3):
    the target at the centre of their bounding box, the camera along :data:`VIEW_DIRECTION`
    far enough for a sphere around the box (at least ``min_radius``) to fill ``1/margin`` of
    the view's height. Non-finite points are left out."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not len(pts):
        return np.zeros(3), cast(tuple[float, float, float], tuple(0.3 * VIEW_DIRECTION))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), min_radius)
    distance = margin * radius / np.sin(np.radians(0.5 * CAMERA_FOV_DEG))
    offset = distance * VIEW_DIRECTION
    return 0.5 * (lo + hi), (float(offset[0]), float(offset[1]), float(offset[2]))


def scene_points(
    hand: HandModel,
    states: Sequence[tuple[FloatArray, FloatArray | None]],
    objects: Sequence[tuple[FloatArray, float]],
) -> FloatArray:
    """Points (N, 3) [m, world] a camera must show: the origin of every link of the hand at
    each ``(q, wMb)`` of ``states`` (``wMb`` None: the hand's mount) and the six extreme points
    of a sphere about each ``(centre, radius)`` of ``objects``. (A table under them shows from
    :data:`VIEW_DIRECTION`, which looks down on the scene.)"""
    kin = HandKinematics(hand)
    out = []
    for q, wMb in states:
        kin.update(q, hand.wMb if wMb is None else wMb)
        out += [kin.frame_pose(name)[:3, 3] for name in hand.all_link_names]
    for centre, radius in objects:
        c = np.asarray(centre, dtype=float)
        out += [c + radius * d for d in np.concatenate((np.eye(3), -np.eye(3)))]
    return np.asarray(out, dtype=float).reshape(-1, 3)


class _OnTop(mg.Mesh):
    """A mesh drawn after everything else (three.js ``renderOrder``)."""

    def lower(self) -> dict[str, Any]:
        data = super().lower()
        data["object"]["renderOrder"] = 10
        return data


def _hex(rgb: Any) -> int:
    r, g, b = (int(round(255 * float(np.clip(c, 0, 1)))) for c in list(rgb)[:3])
    return (r << 16) | (g << 8) | b


def _visual_mesh(geom: pin.GeometryObject) -> trimesh.Trimesh | None:
    """A visual geometry's mesh in its placement frame (scaled), or None if it has no mesh file."""
    path = getattr(geom, "meshPath", "")
    if not path:
        log.warning("viz: geometry %s has no mesh file; primitives are not drawn yet", geom.name)
        return None
    try:
        mesh = cast(trimesh.Trimesh, trimesh.load(path, force="mesh"))
    except Exception as err:  # noqa: BLE001 - a missing visual is not fatal for a viewer
        log.warning("viz: cannot load mesh %s of %s: %s", path, geom.name, err)
        return None
    mesh.apply_transform(np.diag([*np.asarray(geom.meshScale, dtype=float), 1.0]))
    return mesh
