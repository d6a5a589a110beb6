"""ROS 2 topics over DDS, written the way ROS 2's DDS middlewares write them.

A ROS 2 node on rmw_cyclonedds_cpp or rmw_fastrtps_cpp (a stock ROS 2 install) publishes a
topic ``/name`` as the DDS topic ``rt/name`` of the type ``<pkg>::msg::dds_::<Type>_`` in the
domain ``ROS_DOMAIN_ID``, with plain little-endian CDR (XCDR1) payloads; from Iron on every
endpoint's USER_DATA QoS carries ``typehash=RIHS01_<sha256>;`` and the participant's
``enclave=/;``. This module does the same through Cyclone DDS's Python binding (its wheel
carries the C library, so no ROS installation is needed): the message types below are the ROS 2
messages wholehand speaks as Cyclone IDL structs (:mod:`wholehand.ros2.dds_messages`), their
serialised bytes those of :mod:`wholehand.ros2.messages` (tested byte for byte).

QoS as rmw_cyclonedds maps it: reliable (blocking up to 100 ms; rmw uses forever) or best
effort, keep last ``depth`` or keep all, volatile, automatic liveliness, no auto-dispose.

Discovery: with ``[ros2] dds_peers`` and ``dds_interface`` empty, Cyclone DDS's defaults (or the
file in ``$CYCLONEDDS_URI``): multicast discovery on the default interface, as a stock ROS 2
node. With peers, multicast is off and only those addresses are asked (unicast; what a
network without multicast, or two processes on one machine, need).

ROS 2's graph: as rmw does, each node publishes on the DDS topic ``ros_discovery_info``
(``rmw_dds_common/msg/ParticipantEntitiesInfo``; reliable, transient local, keep last 1) its
participant's GID, its name and namespace and the GIDs (DDS GUIDs, 16 bytes from Jazzy on) of
its readers and writers, again after each new endpoint; ``ros2 node list`` and ``ros2 node
info`` read it (not with ``distro = "humble"``, whose GIDs are 24 bytes). ``ros2 topic list``
and ``ros2 topic info`` read DDS's own discovery.
"""

from __future__ import annotations

import threading
import time
from typing import Any
from xml.sax.saxutils import quoteattr

from cyclonedds._clayer import ddspy_take, ddspy_write_ts
from cyclonedds.core import (
    DDSException,
    InstanceState,
    Listener,
    Policy,
    Qos,
    SampleState,
    ViewState,
)
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from wholehand.errors import ConfigError
from wholehand.ros2.config import HardwareConfig, QoS
from wholehand.ros2.dds_messages import IDL_TYPES, ParticipantEntitiesInfo, graph_message
from wholehand.ros2.messages import MessageError, type_hash
from wholehand.ros2.transport import Received, Rejected, SampleMeta

TOPIC_PREFIX = "rt"
"""ROS 2's prefix of a topic's DDS name (``rt/joint_states``)."""
MAX_BLOCKING = 0.1
"""Longest a reliable write waits for a full reader queue [s]: a control cycle must not stall
on a slow reader (rmw_cyclonedds waits forever)."""
TAKE = 64
"""Samples taken from a reader per call."""
CDR_LE = b"\x00\x01"
"""The encapsulation kind of little-endian plain CDR, the first two bytes of a payload."""
ANY_STATE = SampleState.Any | ViewState.Any | InstanceState.Any
"""Take every sample, read or not."""
DISCOVERY_TOPIC = "ros_discovery_info"
"""rmw's graph topic (no ``rt/`` prefix: it is not a ROS topic)."""


def dds_topic_name(topic: str) -> str:
    """``/hand/commands`` -> ``rt/hand/commands``."""
    if not topic.startswith("/"):
        raise ConfigError(f"topic {topic!r} must be an absolute ROS 2 name, e.g. '/joint_states'")
    return TOPIC_PREFIX + topic


def domain_xml(config: HardwareConfig) -> str | None:
    """Cyclone DDS's configuration for the config's ``dds_interface`` and ``dds_peers``; None
    when both are empty (Cyclone's defaults or ``$CYCLONEDDS_URI``)."""
    if not config.dds_interface and not config.dds_peers:
        return None
    general = ""
    if config.dds_interface:
        key = "address" if config.dds_interface[:1].isdigit() else "name"
        general += f"<Interfaces><NetworkInterface {key}={quoteattr(config.dds_interface)}/>"
        general += "</Interfaces>"
    discovery = ""
    if config.dds_peers:
        general += "<AllowMulticast>false</AllowMulticast>"
        peers = "".join(f"<Peer address={quoteattr(p)}/>" for p in config.dds_peers)
        discovery = f"<Discovery><ParticipantIndex>auto</ParticipantIndex><Peers>{peers}</Peers>"
        discovery += "<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex></Discovery>"
    return (
        f'<CycloneDDS><Domain Id="{config.domain_id}"><General>{general}</General>'
        f"{discovery}</Domain></CycloneDDS>"
    )


_domains: dict[int, tuple[str | None, Domain | None]] = {}
_domains_lock = threading.Lock()


def _domain(config: HardwareConfig) -> None:
    """Create the process's domain ``domain_id`` with the config's settings (once: Cyclone DDS
    keeps one configuration per domain and process); a second config asking other settings
    of the same domain raises :class:`ConfigError`."""
    xml = domain_xml(config)
    with _domains_lock:
        if config.domain_id in _domains:
            if _domains[config.domain_id][0] != xml:
                raise ConfigError(
                    f"{config.path or 'hardware config'}: DDS domain {config.domain_id} is "
                    "already open in this process with other [ros2] dds_interface / dds_peers "
                    "settings; use one setting per domain and process"
                )
            return
        try:
            domain = None if xml is None else Domain(config.domain_id, xml)
        except DDSException as err:
            raise ConfigError(
                f"{config.path or 'hardware config'}: Cyclone DDS refused [ros2] dds_interface="
                f"{config.dds_interface!r} dds_peers={list(config.dds_peers)}: {err}; name an "
                "interface of this machine (ip link) and peer addresses it can reach"
            ) from err
        _domains[config.domain_id] = (xml, domain)


def endpoint_qos(qos: QoS, msgtype: str, distro: str) -> Qos:
    """A ROS 2 QoS profile as rmw_cyclonedds writes it into DDS QoS, with the type hash in
    USER_DATA (not on Humble)."""
    if qos.reliability == "reliable":
        reliability = Policy.Reliability.Reliable(duration(seconds=MAX_BLOCKING))
    else:
        reliability = Policy.Reliability.BestEffort
    history = (
        Policy.History.KeepAll if qos.history == "keep_all" else Policy.History.KeepLast(qos.depth)
    )
    policies: list[Any] = [
        reliability,
        history,
        Policy.Durability.Volatile,
        Policy.Liveliness.Automatic(duration(infinite=True)),
        Policy.WriterDataLifecycle(autodispose=False),
    ]
    if distro != "humble":
        policies.append(Policy.Userdata(f"typehash={type_hash(msgtype)};".encode()))
    return Qos(*policies)


class DdsPublisher:
    """Publishes CDR payloads on one ROS 2 topic over DDS (:class:`~wholehand.ros2.
    transport.TopicPublisher`)."""

    def __init__(self, participant: DomainParticipant, config: HardwareConfig, topic_name: str,
                 msgtype: str) -> None:  # fmt: skip
        self.idl, self.msgtype = IDL_TYPES[msgtype], msgtype
        topic = Topic(participant, dds_topic_name(config.topics[topic_name]), self.idl)
        qos = endpoint_qos(config.qos_of(topic_name), msgtype, config.distro)
        self.writer = DataWriter(participant, topic, qos=qos)
        self.sequence_number = 0
        self._lock = threading.Lock()

    def put(self, payload: bytes, stamp_ns: int | None = None) -> int:
        """Publish ``payload`` (a CDR message of the topic's type, as
        :mod:`wholehand.ros2.messages` encodes it); returns its source timestamp [ns,
        system clock] (``stamp_ns``, or now). Raises :class:`MessageError` when ``payload`` is
        not little-endian CDR.

        The bytes go to Cyclone's writer as they are (the call the binding's
        ``DataWriter.write`` makes after serialising), padded to four bytes as it pads them:
        decoding them into the IDL struct only to serialise it again would cost 50 us."""
        if payload[:2] != CDR_LE or len(payload) < 4:
            raise MessageError(
                f"payload of {len(payload)} bytes is not a little-endian CDR {self.msgtype}"
            )
        data = payload.ljust((len(payload) + 3) & ~3, b"\0")
        with self._lock:
            self.sequence_number += 1
            stamp = time.time_ns() if stamp_ns is None else int(stamp_ns)
            ret = ddspy_write_ts(self.writer._ref, data, stamp)
        if ret < 0:
            raise DDSException(ret, f"writing a {self.msgtype}")
        return stamp

    def close(self) -> None:
        self.writer.__del__()  # Cyclone's Python entities are deleted this way


class DdsSubscriber:
    """Calls ``callback`` from Cyclone DDS's thread for every sample of one ROS 2 topic
    (:class:`~wholehand.ros2.transport.TopicSubscriber`); a sample that does not
    re-serialise goes to ``rejected`` as ``malformed``."""

    def __init__(self, participant: DomainParticipant, config: HardwareConfig, topic_name: str,
                 msgtype: str, callback: Received,
                 rejected: Rejected | None = None) -> None:  # fmt: skip
        self.idl = IDL_TYPES[msgtype]
        topic = Topic(participant, dds_topic_name(config.topics[topic_name]), self.idl)
        qos = endpoint_qos(config.qos_of(topic_name), msgtype, config.distro)
        self._callback, self._rejected = callback, rejected
        self._closed = False
        self.reader = DataReader(
            participant, topic, qos=qos, listener=Listener(on_data_available=self._on_data)
        )

    def _on_data(self, reader: DataReader[Any]) -> None:
        """Take the samples as Cyclone received them, CDR bytes and sample info (the call the
        binding's ``DataReader.take`` makes before deserialising): the callback decodes them."""
        received = time.monotonic()
        taken = ddspy_take(reader._ref, ANY_STATE, TAKE)
        if isinstance(taken, int):  # an error code
            if self._rejected is not None:
                self._rejected("take_failed", f"Cyclone DDS returned {taken} taking samples")
            return
        for data, info in taken:
            if self._closed or not info.valid_data:
                continue  # a writer left (an instance state change, not data)
            meta = SampleMeta(
                int(info.source_timestamp), int(info.publication_handle).to_bytes(16, "little")
            )
            self._callback(bytes(data), meta, received)

    def close(self) -> None:
        self._closed = True
        self.reader.__del__()


class DdsTransport:
    """A ROS 2 node on DDS (module docstring; :class:`~wholehand.ros2.transport.Transport`):
    a participant of the config's domain with ROS 2's participant USER_DATA."""

    def __init__(self, config: HardwareConfig, node_name: str) -> None:
        self.config, self.node_name = config, node_name
        _domain(config)
        try:
            self.participant = DomainParticipant(
                config.domain_id, qos=Qos(Policy.Userdata(b"enclave=/;"))
            )
        except DDSException as err:
            raise ConfigError(
                f"{config.path or 'hardware config'}: Cyclone DDS could not join domain "
                f"{config.domain_id}: {err}"
            ) from err
        self._subscribers: list[DdsSubscriber] = []
        self._publishers: list[DdsPublisher] = []  # Cyclone deletes an entity no one holds
        graph = Topic(self.participant, DISCOVERY_TOPIC, ParticipantEntitiesInfo)
        graph_qos = Qos(
            Policy.Reliability.Reliable(duration(seconds=MAX_BLOCKING)),
            Policy.History.KeepLast(1),
            Policy.Durability.TransientLocal,
            Policy.WriterDataLifecycle(autodispose=False),
        )
        self._graph: DataWriter[ParticipantEntitiesInfo] | None = None
        if config.distro != "humble":  # Humble's GIDs are 24 bytes: another message
            self._graph = DataWriter(self.participant, graph, qos=graph_qos)
        self._announce()

    def _announce(self) -> None:
        """Publish the node's entities on :data:`DISCOVERY_TOPIC` (module docstring; not on
        Humble)."""
        if self._graph is None:
            return

        message = graph_message(
            self.participant.guid.bytes,
            self.node_name,
            [sub.reader.guid.bytes for sub in self._subscribers],
            [pub.writer.guid.bytes for pub in self._publishers],
        )
        self._graph.write(message)

    def publisher(self, topic_name: str, msgtype: str) -> DdsPublisher:
        pub = DdsPublisher(self.participant, self.config, topic_name, msgtype)
        self._publishers.append(pub)
        self._announce()
        return pub

    def subscriber(
        self,
        topic_name: str,
        msgtype: str,
        callback: Received,
        rejected: Rejected | None = None,
    ) -> DdsSubscriber:
        sub = DdsSubscriber(self.participant, self.config, topic_name, msgtype, callback, rejected)
        self._subscribers.append(sub)
        self._announce()
        return sub

    def close(self) -> None:
        for sub in self._subscribers:
            sub.close()
        for pub in self._publishers:
            pub.close()
        self._subscribers.clear()
        self._publishers.clear()
        if self._graph is not None:
            self._graph.__del__()
        self.participant.__del__()
