"""A ROS 2 node on the hardware config's transport (``[ros2] transport``: zenoh or DDS)."""

from __future__ import annotations

from wholehand.ros2.config import HardwareConfig
from wholehand.ros2.transport import Transport


def open_transport(config: HardwareConfig, node_name: str) -> Transport:
    """The node ``node_name`` on the config's transport (``[ros2] transport``)."""
    if config.transport == "dds":
        from wholehand.ros2.ros2_dds import DdsTransport

        return DdsTransport(config, node_name)
    from wholehand.ros2.rmw_zenoh import ZenohTransport

    return ZenohTransport(config, node_name)
