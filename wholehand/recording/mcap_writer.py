"""An MCAP file in rosbag2's layout, and the ROS 2 messages a recording is made of.

:class:`McapWriter` writes rosbag2's MCAP storage: profile ``ros2``, one schema per message type
(``ros2msg``, the definition with its dependencies, of the recording's ROS 2 distro: Jazzy's,
or Humble's, whose Marker lacks only Jazzy's ``ARROW_STRIP`` constant: the bytes are the same),
CDR messages, each channel's ``offered_qos_profiles`` (and from Iron on its
``topic_type_hash``). :class:`MessageTypes`
gives the rosbags message classes by their short names and builds their common parts
(headers, transforms, poses, markers).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from wholehand.errors import ConfigError
from wholehand.ros2.messages import type_hash, typestore

FloatArray = npt.NDArray[np.float64]


MESSAGE_PACKAGES = (
    "builtin_interfaces",
    "std_msgs",
    "geometry_msgs",
    "sensor_msgs",
    "tf2_msgs",
    "visualization_msgs",
)
"""Where :class:`MessageTypes` looks a short message name up, in order."""


FOREVER = {"sec": 2147483647, "nsec": 4294967295}
"""rosbag2's "infinite" duration of a QoS policy."""


def _qos_profile(latched: bool) -> dict[str, Any]:
    """rosbag2's QoS profile of a reliable keep-last publisher, as its metadata lists it."""
    return {
        "history": 1,
        "depth": 1,
        "reliability": 1,
        "durability": 1 if latched else 2,  # transient local / volatile
        "deadline": FOREVER,
        "lifespan": FOREVER,
        "liveliness": 1,
        "liveliness_lease_duration": FOREVER,
        "avoid_ros_namespace_conventions": False,
    }


def _qos(latched: bool) -> str:
    """rosbag2's ``offered_qos_profiles`` of a reliable keep-last publisher (YAML)."""
    durability = 1 if latched else 2  # transient local / volatile
    return (
        f"- history: 1\n  depth: 1\n  reliability: 1\n  durability: {durability}\n"
        "  deadline:\n    sec: 2147483647\n    nsec: 4294967295\n"
        "  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n"
        "  liveliness: 1\n  liveliness_lease_duration:\n    sec: 2147483647\n"
        "    nsec: 4294967295\n  avoid_ros_namespace_conventions: false\n"
    )


class MessageTypes:
    """The rosbags message classes by their short names (``T.Point``: the first of
    :data:`MESSAGE_PACKAGES` that has it), and builders of the messages' common parts."""

    def __init__(self, distro: str = "jazzy") -> None:
        self._all = typestore(distro).types

    def __getattr__(self, name: str) -> Any:
        for package in MESSAGE_PACKAGES:
            cls = self._all.get(f"{package}/msg/{name}")
            if cls is not None:
                setattr(self, name, cls)  # found once
                return cls
        raise AttributeError(f"no message type {name!r} in {MESSAGE_PACKAGES}")

    def header(self, t: float, frame: str = "world") -> Any:
        sec = math.floor(t)
        nanosec = min(int(round((t - sec) * 1e9)), 999_999_999)
        return self.Header(stamp=self.Time(sec=int(sec), nanosec=nanosec), frame_id=frame)

    def transform(self, M: FloatArray) -> Any:
        x, y, z, w = pin.Quaternion(np.asarray(M[:3, :3])).coeffs()
        return self.Transform(
            translation=self.Vector3(x=float(M[0, 3]), y=float(M[1, 3]), z=float(M[2, 3])),
            rotation=self.Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)),
        )

    def points(self, xyz: FloatArray) -> list[Any]:
        return [self.Point(x=float(x), y=float(y), z=float(z)) for x, y, z in xyz]

    def pose(self, M: FloatArray) -> Any:
        tr = self.transform(M)
        v = tr.translation
        return self.Pose(position=self.Point(x=v.x, y=v.y, z=v.z), orientation=tr.rotation)

    def marker(self, header: Any, **fields: Any) -> Any:
        """A Marker with every field not given at its default."""
        values: dict[str, Any] = {
            "header": header,
            "ns": "",
            "id": 0,
            "type": 0,
            "action": 0,
            "pose": self.pose(np.eye(4)),
            "scale": self.Vector3(x=1.0, y=1.0, z=1.0),
            "color": self.ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0),
            "lifetime": self.Duration(sec=0, nanosec=0),
            "frame_locked": False,
            "points": [],
            "colors": [],
            "texture_resource": "",
            "texture": self.CompressedImage(
                header=header, format="", data=np.zeros(0, dtype=np.uint8)
            ),
            "uv_coordinates": [],
            "text": "",
            "mesh_resource": "",
            "mesh_file": self.MeshFile(filename="", data=np.zeros(0, dtype=np.uint8)),
            "mesh_use_embedded_materials": False,
        }
        values.update(fields)
        return self.Marker(**values)


class McapWriter:
    """An MCAP file of ROS 2 messages with rosbag2's conventions (module docstring)."""

    def __init__(self, path: str | Path, distro: str = "jazzy") -> None:
        from mcap.writer import Writer

        self.path = Path(path)
        self.distro = distro
        self._store = typestore(distro)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        except OSError as err:
            raise ConfigError(
                f"cannot write the recording {self.path}: {err.strerror}; give --record a path "
                "in a writable folder"
            ) from err
        self._writer = Writer(self._file)
        self._writer.start(profile="ros2", library="wholehand")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self._latched: dict[str, bool] = {}
        self._counts: dict[str, int] = {}
        self._first = self._last = -1  # log times of the first and last message [ns]
        self._sequence = 0

    def channel(self, topic: str, msgtype: str, latched: bool = False) -> None:
        """Declare ``topic`` of ``msgtype`` (e.g. ``std_msgs/msg/String``)."""
        if msgtype not in self._schemas:
            msgdef = self._store.generate_msgdef(msgtype, ros_version=2)[0]
            self._schemas[msgtype] = self._writer.register_schema(
                msgtype, "ros2msg", msgdef.encode()
            )
        metadata = {"offered_qos_profiles": _qos(latched)}
        if self.distro != "humble":  # type hashes came with Iron
            metadata["topic_type_hash"] = type_hash(msgtype)
        cid = self._writer.register_channel(topic, "cdr", self._schemas[msgtype], metadata)
        self._channels[topic] = (cid, msgtype)
        self._latched[topic] = latched
        self._counts[topic] = 0

    def write(self, topic: str, message: Any, t: float) -> None:
        """Write ``message`` (a rosbags message of the topic's type) at time ``t`` [s]."""
        cid, msgtype = self._channels[topic]
        data = bytes(self._store.serialize_cdr(message, msgtype))
        stamp = max(int(round(t * 1e9)), 0)
        self._sequence += 1
        self._writer.add_message(cid, stamp, data, stamp, self._sequence)
        self._counts[topic] += 1
        self._first = stamp if self._first < 0 else min(self._first, stamp)
        self._last = max(self._last, stamp)

    def close(self) -> None:
        """Write rosbag2's metadata record (what ``ros2 bag info`` reads) and the summary."""
        self._writer.add_metadata("rosbag2", {"serialized_metadata": self.bag_metadata()})
        self._writer.finish()
        self._file.close()

    def bag_metadata(self) -> str:
        """rosbag2's bag metadata (version 9, as ``metadata.yaml`` holds it) of what was written,
        in JSON, which is YAML too."""
        start = max(self._first, 0)
        duration = max(self._last - self._first, 0)
        total = sum(self._counts.values())
        topics = [
            {
                "topic_metadata": {
                    "name": topic,
                    "type": msgtype,
                    "serialization_format": "cdr",
                    "offered_qos_profiles": [_qos_profile(self._latched[topic])],
                    **(
                        {}
                        if self.distro == "humble"
                        else {"type_description_hash": type_hash(msgtype)}
                    ),
                },
                "message_count": self._counts[topic],
            }
            for topic, (_, msgtype) in self._channels.items()
        ]
        info = {
            "version": 9,
            "storage_identifier": "mcap",
            "relative_file_paths": [self.path.name],
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": total,
            "topics_with_message_count": topics,
            "compression_format": "",
            "compression_mode": "",
            "files": [
                {
                    "path": self.path.name,
                    "starting_time": {"nanoseconds_since_epoch": start},
                    "duration": {"nanoseconds": duration},
                    "message_count": total,
                }
            ],
            "custom_data": None,
            "ros_distro": self.distro,
        }
        return json.dumps({"rosbag2_bagfile_information": info}, indent=1)
