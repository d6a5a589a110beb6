"""Runs recorded as MCAP files of standard ROS 2 messages, for Foxglove, PlotJuggler, RViz and
``ros2 bag play``.

The file follows rosbag2's MCAP storage: profile ``ros2``, one schema per message type
(``ros2msg``, the definition with its dependencies, ROS 2 Jazzy's), CDR messages, each
channel's ``offered_qos_profiles``. Every message is stamped (header and log time) with the
run's time: the backend's clock [s] from 0 in a simulation; on a robot (a backend on the wall
clock) the system clock, UNIX time as ROS time is, so that the file lines up with the robot's own
messages and bags (the backend's monotonic clock shifted by the system clock's offset, measured
when the run starts).

Topics (frames: ``world``, every link of the model by its name, and ``object``):

==================================  ==================================  =====================
``/robot_description``              ``std_msgs/msg/String``             the model's URDF, mesh
                                                                        paths as file:// URIs
                                                                        (once, latched)
``/tf``                             ``tf2_msgs/msg/TFMessage``          world -> each link and
                                                                        -> ``object``
``/joint_states``                   ``sensor_msgs/msg/JointState``      q, dq and the applied
                                                                        torques as efforts
``/object_pose``                    ``geometry_msgs/msg/PoseStamped``   the pose the controller
                                                                        saw
``/wholehand/scene``                ``visualization_msgs/msg/           the object's mesh (its
                                    MarkerArray``                       triangles in
                                                                        ``object``), each
                                                                        contact link's in its
                                                                        frame (``hand``) and
                                                                        the table (latched)
``/wholehand/torque_command``       ``std_msgs/msg/Float64MultiArray``  the applied torques
                                                                        [N*m], model order
``/wholehand/joint_targets``        ``sensor_msgs/msg/JointState``      position targets (arm,
                                                                        reacher), when any
``/wholehand/contacts``             ``visualization_msgs/msg/           the contact points and
                                    MarkerArray``                       their forces, coloured
                                                                        by magnitude
``/wholehand/residual_wrench``      ``geometry_msgs/msg/WrenchStamped`` the allocation's net
                                                                        wrench, object's CoM
``/wholehand/status``               ``std_msgs/msg/String``             ``<stage>: <status>``
                                                                        every cycle
``/wholehand/stage``                ``std_msgs/msg/String``             the first stage, then
                                                                        every transition
``/wholehand/run_info``             ``std_msgs/msg/String``             JSON: hand, object,
                                                                        base link, arrow
                                                                        scale, table, spec
                                                                        (latched)
==================================  ==================================  =====================

The contacts are two markers: their points (a SPHERE_LIST) and their forces (a LINE_LIST from
each point to ``point + ARROW_SCALE * force``), coloured by the force's magnitude from blue to
red; contacts without an allocated force are grey, with short lines along the object normal.
:func:`~wholehand.recording.mcap_replay.read_mcap_record` turns a recording back into a run record
for ``wholehand view``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from wholehand.loop.control_loop import ControlLoop, Cycle, Observer
from wholehand.models.hand import HandModel
from wholehand.models.kinematics import HandKinematics
from wholehand.models.mesh_files import resolve_mesh_uri
from wholehand.recording.mcap_writer import McapWriter, MessageTypes

FloatArray = npt.NDArray[np.float64]
log = logging.getLogger(__name__)

ARROW_SCALE = 0.01
"""Length of a contact arrow per newton of force [m/N]."""
FORCE_FULL_COLOUR = 10.0
"""Force whose arrow is fully red; weaker ones shade to blue [N]."""
NORMAL_ARROW = 0.01
"""Length of the normal line of a contact without a force [m]."""
GREY = (0.6, 0.6, 0.6)
"""Colour of a contact without a force."""

STRING = "std_msgs/msg/String"
JOINT_STATE = "sensor_msgs/msg/JointState"
TOPICS: dict[str, tuple[str, bool]] = {
    "/robot_description": (STRING, True),
    "/tf": ("tf2_msgs/msg/TFMessage", False),
    "/joint_states": (JOINT_STATE, False),
    "/object_pose": ("geometry_msgs/msg/PoseStamped", False),
    "/wholehand/scene": ("visualization_msgs/msg/MarkerArray", True),
    "/wholehand/torque_command": ("std_msgs/msg/Float64MultiArray", False),
    "/wholehand/joint_targets": (JOINT_STATE, False),
    "/wholehand/contacts": ("visualization_msgs/msg/MarkerArray", False),
    "/wholehand/residual_wrench": ("geometry_msgs/msg/WrenchStamped", False),
    "/wholehand/status": (STRING, False),
    "/wholehand/stage": (STRING, True),
    "/wholehand/run_info": (STRING, True),
}
"""Topic -> (message type, latched: transient-local, as a late subscriber needs it)."""


def urdf_for_viewers(hand: HandModel) -> str | None:
    """The hand's URDF with every mesh path a ``file://`` URI (viewers cannot resolve the
    model's ``package://`` or relative paths); None for an MJCF model."""
    cfg = hand.config
    if cfg.model_format != "urdf":
        return None
    root = ET.parse(cfg.model_path).getroot()
    for mesh in root.iter("mesh"):
        path = resolve_mesh_uri(mesh.get("filename", ""), cfg.model_path, cfg.package_dirs)
        if path is not None:
            mesh.set("filename", path.resolve().as_uri())
    return ET.tostring(root, encoding="unicode")


def system_time_offset(backend: Any) -> float:
    """The system clock (UNIX time) minus ``backend``'s clock [s] for a backend on the wall
    clock (a robot's, ``time.monotonic``), 0 for a simulation, whose time starts at 0."""
    if getattr(backend, "clock", "sim") != "wall":
        return 0.0
    return time.time() - float(backend.time)


def force_colour(magnitude: float) -> tuple[float, float, float]:
    """Blue (0 N) to red (:data:`FORCE_FULL_COLOUR` and above), as RGB in [0, 1]."""
    s = min(max(magnitude / FORCE_FULL_COLOUR, 0.0), 1.0)
    return s, 0.2, 1.0 - s


class McapRecorder(Observer):
    """Records every cycle of a run into an MCAP file (module docstring).

    Args:
        path: the file to write (``.mcap``).
        info: what else ``/wholehand/run_info`` carries (e.g. the trial spec; ``hand`` and
            ``object`` there are the names ``wholehand view`` loads), JSON-able.

    The hand and the object are the loop's.
    """

    def __init__(
        self, path: str | Path, info: dict[str, Any] | None = None, distro: str = "jazzy"
    ) -> None:
        self.path = Path(path)
        self.info = dict(info or {})
        self.distro = distro
        self.types = MessageTypes(distro)
        self._writer: McapWriter | None = None
        self._stage = ""
        self._transitions = 0
        self._loop: ControlLoop | None = None
        self.stopped = ""
        """Why the recording stopped early ("" while it runs or when it ran to the end)."""

    def report(self) -> str:
        """One line for the user: where the recording is, and whether and why it stopped
        before the run ended (the file then holds the run up to then)."""
        if not self.stopped:
            return f"recording: {self.path}"
        return (
            f"recording: {self.path} STOPPED at {self.stopped}; it holds the run up to then "
            "(`wholehand view` reads it to the cut)"
        )

    def on_start(self, loop: ControlLoop) -> None:
        self._loop = loop
        hand = self.hand = loop.hand
        self.obj = loop.obj
        self.kin = HandKinematics(hand)
        self.links = hand.all_link_names
        self.dof_names = [""] * hand.nv
        """The joint of each velocity index."""
        for name in hand.joint_names:
            self.dof_names[hand.model.joints[hand.model.getJointId(name)].idx_v] = name
        writer = self._writer = McapWriter(self.path, self.distro)
        for topic, (msgtype, latched) in TOPICS.items():
            writer.channel(topic, msgtype, latched)
        self._started = False
        self.time_offset = system_time_offset(loop.backend)
        """What turns the loop's time into the recording's [s] (0 in a simulation)."""

    def _write_latched(self, writer: McapWriter, t: float) -> None:
        """The messages written once, at the first cycle's time ``t`` [s]: the URDF, the run's
        information and the scene (so that a robot's run, on its monotonic clock, starts at
        its first cycle, not at 0)."""
        T = self.types
        urdf = urdf_for_viewers(self.hand)
        if urdf is not None:
            writer.write("/robot_description", T.String(data=urdf), t)
        info = {
            "hand": self.hand.config.name,
            "object": self.obj.name,
            "base_link": self.hand.all_link_names[0],
            "arrow_scale_m_per_N": ARROW_SCALE,
            "joint_names": list(self.hand.joint_names),
            "clock": "system" if self.time_offset else "run",
            **self.info,
        }
        writer.write("/wholehand/run_info", T.String(data=json.dumps(info, default=str)), t)
        corners = np.asarray(self.obj.mesh.vertices, dtype=float)[np.asarray(self.obj.mesh.faces)]
        scene = [
            T.marker(
                T.header(t, "object"),
                ns="object",
                type=11,  # TRIANGLE_LIST: the mesh itself, so the file needs no mesh path
                color=T.ColorRGBA(r=0.8, g=0.6, b=0.3, a=0.8),
                frame_locked=True,
                points=T.points(corners.reshape(-1, 3)),
            )
        ]
        table = self.info.get("table")
        if table:
            box = np.eye(4)
            thickness = float(table.get("thickness", 0.05))
            box[:3, 3] = [*table["centre"], float(table["top"]) - 0.5 * thickness]
            scene.append(
                T.marker(
                    T.header(t),
                    ns="table",
                    type=1,  # CUBE
                    pose=T.pose(box),
                    scale=T.Vector3(x=table["size"][0], y=table["size"][1], z=thickness),
                    color=T.ColorRGBA(r=0.55, g=0.45, b=0.35, a=1.0),
                )
            )
        scene += self._hand_markers(t)
        writer.write("/wholehand/scene", T.MarkerArray(markers=scene), t)

    def _hand_markers(self, t: float) -> list[Any]:
        """Every contact link's surface mesh as a TRIANGLE_LIST marker in that link's frame
        (namespace ``hand``): the hand draws from the file alone, where the URDF's mesh paths
        do not resolve (another computer)."""
        T, hand, kin = self.types, self.hand, self.kin
        kin.update(hand.neutral(), np.eye(4))
        out = []
        for i, link in enumerate(hand.link_names):
            mesh = hand.link_mesh(i)
            if len(mesh.faces) == 0:
                continue
            # The mesh is in the link's parent-joint frame; the marker is in the link's.
            corners = np.asarray(mesh.vertices, dtype=float)[np.asarray(mesh.faces)].reshape(-1, 3)
            joints = np.full(len(corners), int(hand.link_joint[i]), dtype=np.intp)
            world = kin.transform_points(corners, joints)
            wMl = kin.frame_pose(link)
            corners = (world - wMl[:3, 3]) @ wMl[:3, :3]
            out.append(
                T.marker(
                    T.header(t, link),
                    ns="hand",
                    id=i,
                    type=11,  # TRIANGLE_LIST
                    color=T.ColorRGBA(r=0.6, g=0.6, b=0.65, a=1.0),
                    frame_locked=True,
                    points=T.points(corners),
                )
            )
        return out

    def on_cycle(self, cycle: Cycle) -> str | None:
        """Record the cycle; a failure (a full disk, a state that cannot be written) stops the
        recording with a warning and :attr:`stopped` set, never the run."""
        if self._writer is None:
            return None
        try:
            self._record(self._writer, cycle)
        except Exception as err:  # noqa: BLE001 - the recording must not end a robot's run
            self.stopped = f"t = {cycle.t:.3f} s: {type(err).__name__}: {err}"
            log.warning("MCAP recording to %s stopped at %s", self.path, self.stopped)
            with contextlib.suppress(Exception):  # closing may fail for the same reason
                self.on_end(self._loop)
        return None

    def _write_targets(self, writer: McapWriter, cycle: Cycle, header: Any, t: float) -> None:
        """The command's joint position targets, if it has any, on /wholehand/joint_targets."""
        names: list[str] = []
        positions: list[float] = []
        for group in cycle.command.targets:
            if group.q is None:
                continue
            names += [self.dof_names[int(i)] for i in group.dofs]
            positions += [float(v) for v in group.q]
        if not names:
            return
        message = self.types.JointState(
            header=header,
            name=names,
            position=np.asarray(positions),
            velocity=np.zeros(0),
            effort=np.zeros(0),
        )
        writer.write("/wholehand/joint_targets", message, t)

    def _record(self, writer: McapWriter, cycle: Cycle) -> None:
        T, hand = self.types, self.hand
        t = cycle.t + self.time_offset
        if not self._started:
            self._write_latched(writer, t)
            self._started = True
        obs = cycle.truth
        header = T.header(t)
        self.kin.update(obs.q, obs.wMb)
        transforms = [
            T.TransformStamped(
                header=header, child_frame_id=name, transform=T.transform(self.kin.frame_pose(name))
            )
            for name in self.links
        ]
        seen = cycle.context.obs.wMo
        if obs.wMo is not None:
            transforms.append(
                T.TransformStamped(
                    header=header, child_frame_id="object", transform=T.transform(obs.wMo)
                )
            )
        writer.write("/tf", T.TFMessage(transforms=transforms), t)
        writer.write(
            "/joint_states",
            T.JointState(
                header=header,
                name=list(hand.joint_names),
                position=np.asarray(obs.q, dtype=float),
                velocity=np.asarray(obs.dq, dtype=float),
                effort=np.asarray(cycle.command.tau, dtype=float),
            ),
            t,
        )
        if seen is not None:
            writer.write("/object_pose", T.PoseStamped(header=header, pose=T.pose(seen)), t)
        writer.write(
            "/wholehand/torque_command",
            T.Float64MultiArray(
                layout=T.MultiArrayLayout(dim=[], data_offset=0),
                data=np.asarray(cycle.command.tau, dtype=float),
            ),
            t,
        )
        self._write_targets(writer, cycle, header, t)
        self._write_contacts(writer, cycle, header, t)
        allocation = cycle.output.allocation
        if allocation is not None:
            w = np.asarray(allocation.residual_wrench, dtype=float)
            wrench = T.Wrench(
                force=T.Vector3(x=float(w[0]), y=float(w[1]), z=float(w[2])),
                torque=T.Vector3(x=float(w[3]), y=float(w[4]), z=float(w[5])),
            )
            writer.write(
                "/wholehand/residual_wrench", T.WrenchStamped(header=header, wrench=wrench), t
            )
        writer.write("/wholehand/status", T.String(data=f"{cycle.stage}: {cycle.output.status}"), t)
        loop = self._loop
        transitions = [] if loop is None else loop.report.transitions
        if not self._stage:
            self._stage = cycle.stage
            writer.write("/wholehand/stage", T.String(data=f"start: {cycle.stage}"), t)
        for tr in transitions[self._transitions :]:
            text = f"{tr.source} -> {tr.target}: {tr.reason}"
            writer.write("/wholehand/stage", T.String(data=text), tr.t)
        self._transitions = len(transitions)

    def _write_contacts(self, writer: McapWriter, cycle: Cycle, header: Any, t: float) -> None:
        """Two markers: the contact points (``points``, SPHERE_LIST) and their forces
        (``forces``, LINE_LIST: per contact its point and ``point + ARROW_SCALE * force``), each
        vertex coloured by its contact's force; without an allocation, grey points and short
        lines along the object normals."""
        T = self.types
        contacts, allocation = cycle.output.contacts, cycle.output.allocation
        p = np.zeros((0, 3)) if contacts is None else np.asarray(contacts.p_world, dtype=float)
        if allocation is not None and allocation.f_world.shape == p.shape:
            f = np.asarray(allocation.f_world, dtype=float)
            end = p + ARROW_SCALE * f
            rgb = [force_colour(m) for m in np.linalg.norm(f, axis=1)]
        else:
            n = np.zeros_like(p) if contacts is None else np.asarray(contacts.n_world, dtype=float)
            end = p - NORMAL_ARROW * n
            rgb = [GREY] * len(p)
        colours = [T.ColorRGBA(r=r, g=g, b=b, a=1.0) for r, g, b in rgb]
        lines = np.stack((p, end), axis=1).reshape(-1, 3)
        markers = [
            T.marker(
                header,
                ns="points",
                type=7,  # SPHERE_LIST
                scale=T.Vector3(x=0.004, y=0.004, z=0.004),
                points=T.points(p),
                colors=colours,
            ),
            T.marker(
                header,
                ns="forces",
                type=5,  # LINE_LIST
                scale=T.Vector3(x=0.0015, y=0.0, z=0.0),
                points=T.points(lines),
                colors=[c for c in colours for _ in (0, 1)],
            ),
        ]
        writer.write("/wholehand/contacts", T.MarkerArray(markers=markers), t)

    def on_end(self, loop: ControlLoop | None) -> None:
        if self._writer is not None:
            writer, self._writer = self._writer, None
            writer.close()
