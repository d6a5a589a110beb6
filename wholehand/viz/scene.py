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
import io
import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple, cast

import meshcat
import meshcat.geometry as mg
import numpy as np
import numpy.typing as npt
import pinocchio as pin
import trimesh
import umsgpack
from meshcat.servers.tree import SceneTree, find_node, walk

from wholehand.errors import ConfigError
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.models.objects import ObjectModel

if TYPE_CHECKING:
    from wholehand.backends.table import Table

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

FORCE_ARROW_MIN_N = 0.5
"""Smallest commanded contact force drawn as an arrow [N] (paper, Fig. 1 caption)."""
FORCE_COLOURMAP = "plasma"
"""Matplotlib colour map of the force magnitude."""
FORCE_COLOUR_BINS = 8
"""Number of discrete colours of the force scale (one arrow pool per colour)."""
ARROW_M_PER_N = 0.01
"""Arrow length per newton of force [m/N]."""
ARROW_LENGTH_RANGE_M = (0.01, 0.06)
"""Shortest and longest arrow drawn [m]."""
ARROW_RADIUS_M = 0.0015
"""Shaft radius of a force arrow [m]."""
CONTACT_RADIUS_M = 0.002
"""Radius of a contact-point sphere [m]."""
DISTANCE_COLOURMAP = "viridis_r"
"""Matplotlib colour map of the hand's distance to the nearest contact (near = yellow)."""
DISTANCE_RANGE_M = 0.05
"""Distance mapped to the far end of the distance colour map [m]."""
HAND_RGB = (0.25, 0.25, 0.28)
"""Hand colour where the URDF gives none."""
OBJECT_RGB = (0.2, 0.75, 0.7)
TABLE_RGB = (0.55, 0.45, 0.35)
"""Colour of a table."""
"""Object colour (teal, away from the force colour map)."""
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


# --- colour scales ------------------------------------------------------------------------------
@dataclass(frozen=True)
class ColourScale:
    """Discrete colour scale of force magnitudes over [f_min, f_max] [N]."""

    f_min: float = FORCE_ARROW_MIN_N
    """Magnitude at the low end (the arrow threshold) [N]."""
    f_max: float = 5.0
    """Magnitude at the high end; larger forces take the last colour [N]."""
    n_bins: int = FORCE_COLOUR_BINS
    cmap: str = FORCE_COLOURMAP

    def __post_init__(self) -> None:
        if not (
            np.isfinite(self.f_min) and np.isfinite(self.f_max) and self.f_max > self.f_min >= 0
        ):
            raise ConfigError(
                f"ColourScale: need 0 <= f_min < f_max (finite) [N], "
                f"got {self.f_min!r}, {self.f_max!r}"
            )
        if self.n_bins < 1:
            raise ConfigError(f"ColourScale: n_bins must be >= 1, got {self.n_bins!r}")

    @classmethod
    def for_forces(cls, magnitudes: npt.ArrayLike, f_min: float = FORCE_ARROW_MIN_N) -> ColourScale:
        """From f_min to the largest magnitude rounded up to whole newtons (>= f_min + 1)."""
        m = np.asarray(magnitudes, dtype=float)
        top = float(np.ceil(m.max())) if m.size else 0.0
        return cls(f_min=f_min, f_max=max(top, f_min + 1.0))

    def bin(self, magnitude: npt.ArrayLike) -> IntArray:
        """(N,) colour-bin index of each magnitude, clipped to [0, n_bins - 1]."""
        u = (np.asarray(magnitude, dtype=float) - self.f_min) / (self.f_max - self.f_min)
        return np.clip(np.floor(u * self.n_bins), 0, self.n_bins - 1).astype(np.intp)

    def bin_rgb(self) -> FloatArray:
        """(n_bins, 3) RGB in [0, 1] of every bin (the colour map at the bin centres)."""
        from matplotlib import colormaps

        centres = (np.arange(self.n_bins) + 0.5) / self.n_bins
        return np.asarray(colormaps[self.cmap](centres))[:, :3]

    def rgb(self, magnitude: npt.ArrayLike) -> FloatArray:
        """(N, 3) RGB in [0, 1] of each magnitude."""
        return self.bin_rgb()[self.bin(magnitude)]

    def bin_edges(self) -> FloatArray:
        """(n_bins + 1,) magnitudes at the bin edges [N]."""
        return np.linspace(self.f_min, self.f_max, self.n_bins + 1)

    def legend_png(self, width_px: int = 140, height_px: int = 260) -> bytes:
        """A vertical colour bar with magnitude ticks, as PNG bytes (matplotlib, Agg)."""
        from matplotlib.colors import BoundaryNorm, ListedColormap
        from matplotlib.figure import Figure

        dpi = 100
        fig = Figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi, facecolor="white")
        ax = fig.add_axes((0.12, 0.05, 0.22, 0.82))
        edges = self.bin_edges()
        cmap = ListedColormap(self.bin_rgb())
        norm = BoundaryNorm(edges, cmap.N)
        from matplotlib.cm import ScalarMappable

        bar = fig.colorbar(
            ScalarMappable(norm=norm, cmap=cmap), cax=ax, ticks=edges[:: max(1, self.n_bins // 4)]
        )
        bar.ax.tick_params(labelsize=8)
        ax.set_title("|f| [N]", fontsize=9, loc="left", pad=6)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi, facecolor="white")
        return buf.getvalue()


def distance_to_nearest_contact(points: FloatArray, contact_p: FloatArray) -> FloatArray:
    """(P,) distance of each point to the nearest contact point [m]; inf where there is none."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    contact_p = np.asarray(contact_p, dtype=float).reshape(-1, 3)
    if contact_p.shape[0] == 0:
        return np.full(points.shape[0], np.inf)
    from scipy.spatial import cKDTree

    d, _ = cKDTree(contact_p).query(points)
    return np.asarray(d, dtype=float)


def distance_rgb(
    distance: FloatArray, d_max: float = DISTANCE_RANGE_M, cmap: str = DISTANCE_COLOURMAP
) -> FloatArray:
    """(P, 3) RGB in [0, 1] of distances [m], clipped to [0, d_max] (inf takes the far colour)."""
    from matplotlib import colormaps

    u = np.clip(np.nan_to_num(np.asarray(distance, dtype=float), posinf=d_max) / d_max, 0.0, 1.0)
    return np.asarray(colormaps[cmap](u))[:, :3]


# --- force arrows -------------------------------------------------------------------------------
class ForceArrows(NamedTuple):
    """The force arrows of one cycle (N of them, forces of at least the threshold)."""

    row: IntArray
    """(N,) row of each arrow in the cycle's contact arrays."""
    tip: FloatArray
    """(N, 3) arrow tips: the contact points, world frame [m]."""
    direction: FloatArray
    """(N, 3) unit directions of the forces on the object, world frame."""
    magnitude: FloatArray
    """(N,) force magnitudes [N]."""
    length: FloatArray
    """(N,) drawn arrow lengths [m]."""


def force_arrows(
    contact_p: npt.ArrayLike, contact_f: npt.ArrayLike, min_force: float = FORCE_ARROW_MIN_N
) -> ForceArrows:
    """The arrows to draw: contacts whose commanded force is at least ``min_force`` [N].

    The arrow ends at the contact point and points along the force on the object, so it shows
    the hand pushing on the object from outside.
    """
    p = np.asarray(contact_p, dtype=float).reshape(-1, 3)
    f = np.asarray(contact_f, dtype=float).reshape(-1, 3)
    if p.shape != f.shape:
        raise ConfigError(
            f"force_arrows: contact_p {p.shape} and contact_f {f.shape} differ in shape"
        )
    magnitude = np.linalg.norm(f, axis=1)
    keep = np.flatnonzero(magnitude >= min_force)
    m = magnitude[keep]
    lo, hi = ARROW_LENGTH_RANGE_M
    return ForceArrows(
        row=keep,
        tip=p[keep],
        direction=f[keep] / np.maximum(m, 1e-12)[:, None],
        magnitude=m,
        length=np.clip(ARROW_M_PER_N * m, lo, hi),
    )


def _y_to(direction: FloatArray) -> FloatArray:
    """(3, 3) rotation taking +y to a unit direction."""
    R = pin.Quaternion.FromTwoVectors(np.array([0.0, 1.0, 0.0]), np.asarray(direction, dtype=float))
    return R.toRotationMatrix()


# --- an offline window ----------------------------------------------------------------------------
class RecordingWindow:
    """A meshcat window without a server: keeps the scene tree to write standalone HTML.

    It stands in for :class:`meshcat.visualizer.ViewerWindow` (``send`` and ``get_scene``), so a
    :class:`meshcat.Visualizer` built on it records commands instead of sending them; the HTML
    embeds meshcat's packaged viewer JavaScript and opens offline from a file.
    """

    web_url: str | None = None

    def __init__(self) -> None:
        self.tree = SceneTree()

    def send(self, command: Any) -> None:
        data = command.lower()
        path = [p for p in data["path"].split("/") if p]
        packed = umsgpack.packb(data)
        kind = data["type"]
        node = find_node(self.tree, path)
        if kind == "set_transform":
            node.transform = packed
        elif kind == "set_object":
            node.object = packed
            node.properties = []
        elif kind == "set_property":
            node.properties.append(packed)
        elif kind == "set_animation":
            node.animation = packed
        elif kind == "delete":
            if path:
                find_node(self.tree, path[:-1]).pop(path[-1], None)
            else:
                self.tree = SceneTree()

    def get_scene(self, overlay_html: str = "", title: str = "wholehand") -> str:
        """Standalone HTML of the scene (viewer JS inlined; data as base64 msgpack).

        Unlike meshcat's own ``static_html`` (one asynchronous ``fetch`` per command, resolved
        in any order), the commands are decoded and run synchronously in tree order, parents
        first, with animations last, so every node exists before the animation binds to it.
        """
        import meshcat.servers.zmqserver as zs

        scene, animations = [], []
        for node in walk(self.tree):
            for packed in [node.object, *node.properties, node.transform]:
                if packed is not None:
                    scene.append(packed)
            if node.animation is not None:
                animations.append(node.animation)
        blobs = ",\n".join(f'"{base64.b64encode(b).decode("ascii")}"' for b in scene + animations)
        with open(f"{zs.VIEWER_ROOT}/main.min.js", encoding="utf-8") as f:
            viewer_js = f.read()
        return _HTML.format(title=title, viewer_js=viewer_js, commands=blobs, overlay=overlay_html)

    def open(self) -> RecordingWindow:
        return self

    def close(self) -> None:
        pass


_HTML = """<!DOCTYPE html>
<html>
<head><meta charset="utf-8"><title>{title}</title>
<style>body {{margin: 0;}} #meshcat-pane {{width: 100vw; height: 100vh; overflow: hidden;}}
#wholehand-overlay {{position: fixed; left: 8px; bottom: 8px; pointer-events: none;
 font: 12px sans-serif; background: rgba(255,255,255,0.85);}}</style></head>
<body>
<div id="meshcat-pane"></div>
<script>
{viewer_js}
</script>
<script>
var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
var commands = [
{commands}
];
for (const b64 of commands) {{
  const bin = atob(b64);
  const bytes = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
  viewer.handle_command_bytearray(bytes);
}}
</script>
{overlay}
</body>
</html>
"""


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
                M[:3, :3] = _y_to(arrows.direction[i])
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
