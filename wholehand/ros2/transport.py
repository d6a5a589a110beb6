"""How ROS 2 messages travel: one interface over zenoh (as rmw_zenoh) and DDS (as rmw_cyclonedds
and rmw_fastrtps), chosen by the hardware config's ``[ros2] transport``.

A transport is one ROS 2 node's presence on the network. It publishes and subscribes CDR
payloads (the 4-byte encapsulation header included, :mod:`wholehand.ros2.messages`) on the
config's topics with their QoS, and hands every received sample to a callback with its
:class:`SampleMeta`. A sample the transport itself must drop (a zenoh sample without rmw_zenoh's
attachment, a DDS sample whose payload does not decode) goes to the ``rejected`` callback with a
reason instead.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol


@dataclass(frozen=True)
class SampleMeta:
    """What a transport knows about a received sample besides its payload."""

    source_timestamp: int
    """When the publisher sent it [ns, the publisher's system clock]: the attachment's stamp
    on zenoh, DDS's source timestamp on DDS; the ``stamp_ns`` given to
    :meth:`TopicPublisher.put`."""
    source: bytes
    """(16,) identity of the publisher (rmw_zenoh's GID; DDS's publication handle)."""
    sequence_number: int = 0
    """The publisher's count of the sample (rmw_zenoh's attachment); 0 where the transport does
    not carry it (DDS)."""


Received = Callable[[bytes, SampleMeta, float], None]
"""``(payload, meta, receipt time on time.monotonic [s])``."""
Rejected = Callable[[str, str], None]
"""``(reason, detail)`` of a sample the transport dropped."""


class TopicPublisher(Protocol):
    """Publishes CDR payloads on one topic."""

    sequence_number: int
    """Samples published so far."""

    def put(self, payload: bytes, stamp_ns: int | None = None) -> int:
        """Publish ``payload``; returns the source timestamp it carries [ns, system clock]
        (``stamp_ns``, or now)."""
        ...

    def close(self) -> None: ...


class TopicSubscriber(Protocol):
    """Receives one topic's samples until closed."""

    def close(self) -> None: ...


class Transport(Protocol):
    """One ROS 2 node on zenoh or DDS (module docstring)."""

    def publisher(self, topic_name: str, msgtype: str) -> TopicPublisher:
        """A publisher of the config's topic ``topic_name`` (a key of ``[topics]``) with its
        QoS; ``msgtype`` e.g. ``sensor_msgs/msg/JointState``."""
        ...

    def subscriber(
        self,
        topic_name: str,
        msgtype: str,
        callback: Received,
        rejected: Rejected | None = None,
    ) -> TopicSubscriber:
        """Call ``callback`` from the transport's thread for every sample of the config's
        topic ``topic_name``; ``rejected`` for every sample dropped (ignored without it)."""
        ...

    def close(self) -> None:
        """Leave the network: every publisher and subscriber of the node closes."""
        ...
