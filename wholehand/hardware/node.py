"""A ROS 2 node on the hardware config's transport (``[ros2] transport``: zenoh or DDS)."""

from __future__ import annotations

from wholehand.hardware.config import HardwareConfig
from wholehand.hardware.transport import Transport


def open_transport(config: HardwareConfig, node_name: str) -> Transport:
    """The node ``node_name`` on the config's transport (``[ros2] transport``)."""
    if config.transport == "dds":
        from wholehand.hardware.ros2_dds import DdsTransport

        return DdsTransport(config, node_name)
    from wholehand.hardware.rmw_zenoh import ZenohTransport

    return ZenohTransport(config, node_name)
