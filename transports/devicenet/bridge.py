"""The DeviceNet simulator's loopback bridge: the core's python-can-remote bridge, telling clients the URL.

Another process reaches the simulated slaves with ``devicenet://remote/127.0.0.1:PORT?mac=5``.
"""

from __future__ import annotations

from starterbus.core.canbridge import DEFAULT_PORT, LoopbackBridge, parse_bridge_address


def devicenet_bridge(interface: str, channel: str, host: str = "127.0.0.1", port: int = DEFAULT_PORT) -> LoopbackBridge:
    return LoopbackBridge(
        interface, channel, host, port, label="devicenet bridge", client_url="devicenet://remote/{address}?mac=N"
    )


__all__ = ["DEFAULT_PORT", "LoopbackBridge", "devicenet_bridge", "parse_bridge_address"]
