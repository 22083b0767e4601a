"""starterbus: one protocol-neutral model for RENLE soft starters over Modbus RTU, Profibus DP and DeviceNet."""

from starterbus.core import (
    Command,
    Device,
    Profile,
    StarterbusError,
    Status,
    load_profile,
    open_device,
)

__all__ = [
    "Command",
    "Device",
    "Profile",
    "StarterbusError",
    "Status",
    "load_profile",
    "open_device",
]
__version__ = "0.1.0"
