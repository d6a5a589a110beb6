"""How the benchmarks connect a controller and the robot double on one machine."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from wholehand.ros2.config import HardwareConfig
from wholehand.ros2.rmw_zenoh import loopback_endpoint

TRANSPORTS = ("zenoh", "dds")
"""The transports a benchmark can run the robot path over."""
DDS_LOOPBACK: dict[str, Any] = {"dds_interface": "127.0.0.1", "dds_peers": ("127.0.0.1",)}
"""The DDS settings of a controller and a double on one machine."""


def loopback(
    config: HardwareConfig, transport: str, listen: tuple[str, ...] = ()
) -> tuple[HardwareConfig, list[str]]:
    """The controller's ``config`` set to reach a double on this machine over ``transport``
    (zenoh: a free TCP port the double listens on; dds: unicast on loopback, in the domain of
    the config or ``$ROS_DOMAIN_ID``), and the ``wholehand hw-sim`` arguments that match;
    ``listen``: zenoh endpoints the controller listens on too (for a third node)."""
    if transport == "dds":
        link = ["--transport", "dds", "--dds-peer", "127.0.0.1", "--dds-interface", "127.0.0.1"]
        return replace(config, transport="dds", **DDS_LOOPBACK), link
    endpoint = loopback_endpoint()
    controller = replace(config, transport="zenoh", connect=(endpoint,), listen=listen)
    return controller, ["--listen", endpoint, "--connect"]
