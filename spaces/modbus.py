"""The ``modbus`` address space: a model's Modbus holding registers (FC03 reads, FC06 writes), public API.

A model has it with a ``[transports.modbus]`` table (``[transports.modbus-rtu]`` in profiles written before
address spaces: the same space) and a ``modbus = 0x0103`` field on each point it addresses. Every transport that
declares ``address_space = "modbus"`` serves every such model; it reads the table's typed settings with::

    from starterbus.spaces.modbus import ModbusSettings

    settings = ModbusSettings.of(profile)
    settings.max_read_registers, settings.unit_ids, settings.exception_text(4)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

from starterbus.core import AddressSpace, Label, Profile
from starterbus.core import settings_check as check

SPACE_NAME = "modbus"
MAX_READ_REGISTERS = 125  # Modbus application protocol limit for FC03
MAX_UNIT = 247  # 248-255 are reserved by Modbus

#: the Modbus application protocol's texts, used where a model's table does not name a code
STANDARD_EXCEPTION_TEXTS: Mapping[int, str] = {
    0x01: "illegal function",
    0x02: "illegal data address",
    0x03: "illegal data value",
    0x04: "server device failure",
    0x05: "acknowledge",
    0x06: "server device busy",
    0x08: "memory parity error",
    0x0A: "gateway path unavailable",
    0x0B: "gateway target device failed to respond",
}
#: exception codes a gateway sends for the device behind it: it is unreachable, it refused nothing
GATEWAY_EXCEPTIONS = frozenset({0x0A, 0x0B})


@dataclass(frozen=True, slots=True)
class ModbusSettings:
    """What a model says about its Modbus slave (each key's one default here)."""

    max_read_registers: int = MAX_READ_REGISTERS  # registers one FC03 may read
    unit_ids: tuple[int, int] = (1, MAX_UNIT)  # slave addresses (0, broadcast, is always accepted by a client)
    baudrates: tuple[int, ...] = ()  # the speeds its serial interface offers (empty: any)
    default_baudrate: int = 9600
    exceptions: Mapping[int, Label] = field(default_factory=check.no_table)  # code -> the manual's text

    @classmethod
    def parse(cls, settings: Mapping[str, Any]) -> ModbusSettings:
        """Unknown keys and wrong values: ConfigurationError naming them (``exceptions`` the loader parsed)."""
        check.int_value(settings, "max_read_registers", 1, MAX_READ_REGISTERS)
        check.int_range(settings, "unit_ids", 0, MAX_UNIT)
        check.int_list(settings, "baudrates", 1, 10_000_000)
        check.int_value(settings, "default_baudrate", 1, 10_000_000)
        return check.build(cls, settings)

    @classmethod
    def of(cls, profile: Profile | None) -> ModbusSettings:
        """The model's settings (no model: the defaults); ConfigurationError if it has no Modbus registers."""
        return profile.settings_for(SPACE_NAME, cls) if profile is not None else cls()

    def exception_text(self, code: int) -> str:
        """What exception ``code`` means on this model: the manual's text where the model's table names the
        code; a gateway's 0x0A / 0x0B (not the device's) by the Modbus application protocol; else "unknown
        exception code N" (the manual does not define it: the protocol's generic text could mislead)."""
        label = self.exceptions.get(code)
        if label is not None:
            return str(label)
        if code in GATEWAY_EXCEPTIONS:
            return STANDARD_EXCEPTION_TEXTS[code]
        return f"unknown exception code {code}"


class ModbusRegisters(AddressSpace):
    """Holding registers 0x0000-0xFFFF; a point's address is its register number."""

    name = SPACE_NAME
    summary = "Modbus holding registers (FC03 / FC06)"
    requires_point_addresses = True

    def parse_settings(self, settings: Mapping[str, Any]) -> ModbusSettings:
        return ModbusSettings.parse(settings)


SPACE = ModbusRegisters()


@runtime_checkable
class RegisterAccess(Protocol):
    """Raw holding-register access, below the model (``read --raw``, ``write --raw``): a transport of the
    ``modbus`` space offers it by having these methods (the built-in ``modbus-rtu`` and ``modbus-tcp`` do).
    Nothing here checks a model's ranges: the caller guards (confirmation, audit, state)."""

    def read_registers(self, address: int, count: int) -> tuple[int, ...]:
        """FC03: ``count`` registers from ``address``, in one request; an exception answer raises."""
        ...

    def write_register(self, address: int, value: int) -> None:
        """FC06: ``value`` (0..0xFFFF) into ``address``, sent once; an exception answer raises."""
        ...

    def preview_register_write(self, address: int, value: int) -> list[str]:
        """The exact frames :meth:`write_register` would send (hex), sending nothing."""
        ...


__all__ = [
    "GATEWAY_EXCEPTIONS",
    "MAX_READ_REGISTERS",
    "MAX_UNIT",
    "SPACE",
    "SPACE_NAME",
    "STANDARD_EXCEPTION_TEXTS",
    "ModbusRegisters",
    "ModbusSettings",
    "RegisterAccess",
]
