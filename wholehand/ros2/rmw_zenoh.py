"""ROS 2 topics over eclipse-zenoh, written the way rmw_zenoh writes them.

A ROS 2 node on rmw_zenoh publishes a topic's messages on the key expression

    <domain_id>/<topic without its leading slash>/<pkg>::msg::dds_::<Type>_/<type hash>

(the type hash is ``RIHS01_<sha256>`` from Iron on, the literal ``TypeHashNotSupported`` on
Humble) with a CDR payload, and attaches to every sample its sequence number, source timestamp
[ns] and the publisher's 16-byte GID, serialised with zenoh-ext (33 bytes). Publishing and
subscribing the same way makes wholehand's topics ordinary topics to every rmw_zenoh node,
without a ROS installation here.

Each process also declares rmw_zenoh's liveliness tokens, which is how ROS 2's graph tools
(``ros2 node list``, ``ros2 topic list``, ``ros2 topic info``) discover entities: one for its
node and one per publisher and subscriber (:class:`Node`), in rmw_zenoh's layout

    @ros2_lv/<domain>/<zenoh id>/<node id>/<entity id>/<NN|MP|MS>/<enclave>/<namespace>/<node>
        [/<topic>/<type>/<type hash>/<qos>]

with every ``/`` inside a name written ``%`` and the QoS as
``<reliability>:<durability>:<history>,<depth>:<deadline>:<lifespan>:<liveliness>`` (rmw's enum
values; empty fields take the defaults).
"""

from __future__ import annotations

import os
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh
import zenoh.ext

from wholehand.errors import ConfigError
from wholehand.ros2.config import HardwareConfig, QoS
from wholehand.ros2.messages import MessageError, dds_type_name, type_hash
from wholehand.ros2.transport import Received, Rejected, SampleMeta

GID_BYTES = 16


def topic_key(domain_id: int, topic: str, msgtype: str, distro: str = "jazzy") -> str:
    """The zenoh key expression rmw_zenoh uses for ``topic`` (an absolute ROS 2 name)."""
    if not topic.startswith("/"):
        raise ConfigError(f"topic {topic!r} must be an absolute ROS 2 name, e.g. '/joint_states'")
    digest = "TypeHashNotSupported" if distro == "humble" else type_hash(msgtype)
    return f"{domain_id}/{topic.strip('/')}/{dds_type_name(msgtype)}/{digest}"


@dataclass(frozen=True)
class Attachment:
    """rmw_zenoh's per-sample attachment."""

    sequence_number: int
    source_timestamp: int
    """Publish time [ns] of the publisher's system clock."""
    gid: bytes
    """(16,) the publisher's global id."""

    def encode(self) -> bytes:
        """zenoh-ext serialisation: int64, int64, then the GID as a length-prefixed buffer."""
        ext = zenoh.ext
        value = (ext.Int64(self.sequence_number), ext.Int64(self.source_timestamp), self.gid)
        return bytes(ext.z_serialize(value).to_bytes())

    @classmethod
    def decode(cls, data: bytes) -> Attachment:
        """Raises :class:`MessageError` when ``data`` is not such an attachment."""
        ext = zenoh.ext
        try:
            seq, stamp, gid = ext.z_deserialize(
                tuple[ext.Int64, ext.Int64, bytes], zenoh.ZBytes(data)
            )
        except Exception as err:  # noqa: BLE001 - a bad attachment is a malformed message
            raise MessageError(
                f"attachment of {len(data)} bytes is not rmw_zenoh's: {err}"
            ) from err
        if len(gid) != GID_BYTES:
            raise MessageError(f"attachment GID has {len(gid)} bytes, rmw_zenoh's has 16")
        return cls(int(seq), int(stamp), bytes(gid))


def open_session(config: HardwareConfig) -> zenoh.Session:
    """A zenoh session with the config's mode and endpoints, multicast scouting off (as
    rmw_zenoh's default session config: peers meet through the listed endpoints)."""
    conf = zenoh.Config()
    try:
        conf.insert_json5("mode", f'"{config.mode}"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("connect/endpoints", _json_list(config.connect))
        conf.insert_json5("listen/endpoints", _json_list(config.listen))
        return zenoh.open(conf)
    except zenoh.ZError as err:
        raise ConfigError(
            f"{config.path or 'hardware config'}: zenoh could not open a session with connect="
            f"{list(config.connect)} listen={list(config.listen)}: {err}; check the [ros2] "
            "endpoints (e.g. 'tcp/127.0.0.1:7447') and that no other process listens there"
        ) from err


def loopback_endpoint() -> str:
    """A zenoh TCP endpoint on 127.0.0.1 at a port free now (the OS picks it), for a double and
    a controller on one machine."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _json_list(items: tuple[str, ...]) -> str:
    return "[" + ",".join(f'"{s}"' for s in items) + "]"


LIVELINESS = "@ros2_lv"
"""rmw_zenoh's admin space for liveliness tokens."""
RELIABILITY = {"reliable": 1, "best_effort": 2}
"""rmw's ``rmw_qos_reliability_policy_e`` values."""
HISTORY = {"keep_last": 1, "keep_all": 2}
"""rmw's ``rmw_qos_history_policy_e`` values."""
VOLATILE = 2
"""rmw's ``RMW_QOS_POLICY_DURABILITY_VOLATILE`` (wholehand publishes no late-joiner history)."""


def mangle(name: str) -> str:
    """A ROS 2 name as one key chunk: every ``/`` written ``%``."""
    return name.replace("/", "%")


def qos_key(qos: QoS) -> str:
    """A QoS profile as rmw_zenoh's liveliness tokens write it (deadline, lifespan and
    liveliness left empty: the defaults)."""
    return f"{RELIABILITY[qos.reliability]}:{VOLATILE}:{HISTORY[qos.history]},{qos.depth}:,:,:,,"


class Node:
    """A ROS 2 node's identity in the graph: declares its liveliness token and, through
    :meth:`token`, those of its publishers and subscribers.

    Args:
        session: the process's zenoh session.
        config: the domain id (and the distro, for type hashes).
        name: the node's name (namespace ``/``).
    """

    def __init__(self, session: zenoh.Session, config: HardwareConfig, name: str) -> None:
        self.session, self.config, self.name = session, config, name
        self.zid = str(session.info.zid())
        self._next_id = 1
        self._tokens: list[Any] = []
        self.keys: list[str] = []
        """Every token declared, in order (the node's first)."""
        self._declare(self._prefix(0, "NN"))

    def _prefix(self, entity_id: int, kind: str) -> str:
        return (
            f"{LIVELINESS}/{self.config.domain_id}/{self.zid}/0/{entity_id}/{kind}/"
            f"{mangle('/')}/{mangle('/')}/{mangle(self.name)}"
        )

    def _declare(self, key: str) -> Any:
        token = self.session.liveliness().declare_token(key)
        self._tokens.append(token)
        self.keys.append(key)
        return token

    def token(self, kind: str, topic_name: str, msgtype: str) -> Any:
        """Declare the token of a publisher (``kind="MP"``) or subscriber (``"MS"``) of the
        config's topic ``topic_name`` (a key of ``[topics]``); returns it (undeclare on close)."""
        config = self.config
        topic = config.topics[topic_name]
        digest = "TypeHashNotSupported" if config.distro == "humble" else type_hash(msgtype)
        key = (
            f"{self._prefix(self._next_id, kind)}/{mangle(topic)}/{dds_type_name(msgtype)}/"
            f"{digest}/{qos_key(config.qos_of(topic_name))}"
        )
        self._next_id += 1
        return self._declare(key)

    def close(self) -> None:
        """Undeclare every token (the node leaves the graph)."""
        for token in self._tokens:
            token.undeclare()
        self._tokens.clear()


class Publisher:
    """Publishes CDR payloads on a ROS 2 topic with rmw_zenoh's attachment (and declares its
    liveliness token when given the ``node``)."""

    def __init__(
        self,
        session: zenoh.Session,
        config: HardwareConfig,
        topic_name: str,
        msgtype: str,
        node: Node | None = None,
    ) -> None:
        qos = config.qos_of(topic_name)
        self.key = topic_key(config.domain_id, config.topics[topic_name], msgtype, config.distro)
        if node is not None:
            node.token("MP", topic_name, msgtype)
        self._pub = session.declare_publisher(
            self.key,
            congestion_control=_congestion(qos),
            reliability=_reliability(qos),
            express=True,
        )
        self.gid = os.urandom(GID_BYTES)
        self.sequence_number = 0
        self._lock = threading.Lock()

    def put(self, payload: bytes, stamp_ns: int | None = None) -> int:
        """Publish; returns the source timestamp written into the attachment [ns, system clock]
        (``stamp_ns``, or now)."""
        with self._lock:
            self.sequence_number += 1
            stamp = time.time_ns() if stamp_ns is None else int(stamp_ns)
            attachment = Attachment(self.sequence_number, stamp, self.gid).encode()
            self._pub.put(payload, attachment=attachment)
        return stamp

    def close(self) -> None:
        self._pub.undeclare()


RawReceived = Callable[[bytes, bytes | None, float], None]
"""``(payload, attachment or None, receipt time on time.monotonic [s])``."""


class Subscriber:
    """Calls ``callback`` from zenoh's thread for every sample of a ROS 2 topic (and declares
    its liveliness token when given the ``node``)."""

    def __init__(
        self,
        session: zenoh.Session,
        config: HardwareConfig,
        topic_name: str,
        msgtype: str,
        callback: RawReceived,
        node: Node | None = None,
    ) -> None:
        self.key = topic_key(config.domain_id, config.topics[topic_name], msgtype, config.distro)
        if node is not None:
            node.token("MS", topic_name, msgtype)

        def handler(sample: zenoh.Sample) -> None:
            received = time.monotonic()
            attachment = sample.attachment
            callback(
                sample.payload.to_bytes(),
                None if attachment is None else attachment.to_bytes(),
                received,
            )

        self._sub = session.declare_subscriber(self.key, handler)

    def close(self) -> None:
        self._sub.undeclare()


def _congestion(qos: QoS) -> zenoh.CongestionControl:
    # rmw_zenoh blocks only for reliable keep-all; otherwise a slow reader drops samples.
    block = qos.reliability == "reliable" and qos.history == "keep_all"
    return zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP


def _reliability(qos: QoS) -> zenoh.Reliability:
    if qos.reliability == "reliable":
        return zenoh.Reliability.RELIABLE
    return zenoh.Reliability.BEST_EFFORT


class ZenohTransport:
    """A ROS 2 node on zenoh as rmw_zenoh makes one (:class:`~wholehand.ros2.transport.
    Transport`): a session with the config's endpoints, the node's liveliness tokens, and
    subscribers that drop samples without rmw_zenoh's attachment (reason ``no_attachment``) or
    with a malformed one (``bad_attachment``), as rmw_zenoh does."""

    def __init__(self, config: HardwareConfig, node_name: str) -> None:
        self.config = config
        self.session = open_session(config)
        try:
            self.node = Node(self.session, config, node_name)
        except Exception:
            self.session.close()
            raise

    def publisher(self, topic_name: str, msgtype: str) -> Publisher:
        return Publisher(self.session, self.config, topic_name, msgtype, self.node)

    def subscriber(
        self,
        topic_name: str,
        msgtype: str,
        callback: Received,
        rejected: Rejected | None = None,
    ) -> Subscriber:
        def handler(payload: bytes, attachment: bytes | None, received: float) -> None:
            if attachment is None:
                if rejected is not None:
                    rejected("no_attachment", "a sample without rmw_zenoh's attachment")
                return
            try:
                meta = Attachment.decode(attachment)
            except MessageError as err:
                if rejected is not None:
                    rejected("bad_attachment", str(err))
                return
            sample = SampleMeta(meta.source_timestamp, meta.gid, meta.sequence_number)
            callback(payload, sample, received)

        return Subscriber(self.session, self.config, topic_name, msgtype, handler, self.node)

    def close(self) -> None:
        self.node.close()
        self.session.close()
