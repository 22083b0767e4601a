"""The model's Modbus settings (the profile's ``[transports.modbus]`` table, typed) and the names the
transport, the slave and the decoder share."""

from __future__ import annotations

from starterbus.core import Profile
from starterbus.spaces.modbus import SPACE_NAME, ModbusSettings

__all__ = ["PROTOCOL", "TRANSPORT", "max_read_registers", "modbus_settings"]

TRANSPORT = "modbus-rtu"
PROTOCOL = SPACE_NAME  # the address space of a point's register: ``modbus = 0x0103`` (``modbus-rtu = `` too)


def modbus_settings(profile: Profile | None) -> ModbusSettings:
    """The model's settings (no model: the defaults)."""
    return ModbusSettings.of(profile)


def max_read_registers(profile: Profile) -> int:
    return modbus_settings(profile).max_read_registers
