"""The JJR8000 application behind a simulated DeviceNet slave node (:class:`StarterApplication`): input
assemblies 1/101 produced from a :class:`SimulatedStarter`'s state, output assemblies 2/102 written to it as the
control word with bit 3 (bus control) set; a lost or idle connection drops its run command."""

from __future__ import annotations

import struct
import time

from starterbus.core import (
    CW_BUS_CONTROL,
    SW_FAULT,
    SW_RUNNING,
    SW_STARTING,
    SW_STOPPING,
    Kind,
    PointDef,
    Refusal,
    SimulatedStarter,
    SimulatorRefusal,
)
from starterbus.transports.devicenet.codec.assemblies import (
    OUTPUT_SIZES,
    AssemblySet,
    InputBit,
    decode_output,
)
from starterbus.transports.devicenet.codec.cip import PROTOCOL
from starterbus.transports.devicenet.settings import devicenet_settings

__all__ = ["IO_REFRESH", "PRO_TYPE_KEY", "StarterApplication"]

IO_REFRESH = 0.001  # seconds: how often a node refreshes its input assembly from the starter
_FAULT = int(InputBit.FAULT)
_WARNING = int(InputBit.WARNING)
_RUNNING = int(InputBit.RUNNING)
_STARTING = int(InputBit.STARTING)
_STOPPING = int(InputBit.STOPPING)
_NETWORK_CONTROL = int(InputBit.NETWORK_CONTROL)
_AT_REFERENCE = int(InputBit.AT_REFERENCE)
PRO_TYPE_KEY = "profibus_type"  # JJR8000 p71: 0 = P1/M1 (basic 1/2), 1 = P3/M2 (extended 101/102)


class StarterApplication:
    """The JJR8000 behind a slave node: assemblies <-> :class:`SimulatedStarter`.

    ``assemblies`` None follows the starter's PRO type parameter (p71) like the real device; a fixed set
    overrides it. The status parameter selected by output assembly 102 byte 1 starts at address 0x01 (status
    word); an address the model does not define reads as 0.
    """

    def __init__(
        self,
        starter: SimulatedStarter,
        assemblies: AssemblySet | None = AssemblySet.EXTENDED,
        io_refresh: float = IO_REFRESH,
    ) -> None:
        self.starter = starter
        self.fixed = assemblies
        self.io_refresh = io_refresh
        self.selected_address = 0x01
        self.outputs: dict[int, bytes] = {instance: bytes(size) for instance, size in OUTPUT_SIZES.items()}
        self._written: int | None = None
        self._points: dict[int, PointDef | None] = {}
        self._cache: dict[int, tuple[float, bytes]] = {}

    def assembly_set(self) -> AssemblySet:
        if self.fixed is not None:
            return self.fixed
        pro_type = self.starter.params.get(PRO_TYPE_KEY, 0)
        return AssemblySet.EXTENDED if pro_type == 1 else AssemblySet.BASIC

    def instance_numbers(self) -> tuple[int, int]:
        return devicenet_settings(self.starter.profile).instances(self.assembly_set())

    def produce(self, instance: int) -> bytes:
        """The input assembly, refreshed from the starter at most every ``io_refresh`` seconds (like the
        internal cycle of a real communication module) and at once after outputs were applied."""
        now = time.monotonic()
        cached = self._cache.get(instance)
        if cached is not None and now - cached[0] < self.io_refresh:
            return cached[1]
        data = self._produce(instance)
        self._cache[instance] = (now, data)
        return data

    def _produce(self, instance: int) -> bytes:
        starter = self.starter
        with starter.lock:
            word = starter.status_word()
            amps = starter.current()
            bits = 0
            if word & SW_FAULT:
                bits |= _FAULT
            if starter.warning:
                bits |= _WARNING
            if word & SW_RUNNING:
                bits |= _RUNNING
            if word & SW_STARTING:
                bits |= _STARTING
            if word & SW_STOPPING:
                bits |= _STOPPING
            if starter.control_word & CW_BUS_CONTROL:
                bits |= _NETWORK_CONTROL
            current = max(0, min(0xFFFF, round(amps)))
            if instance == 1:
                if word & SW_RUNNING and starter.at_reference:
                    bits |= _AT_REFERENCE
                return struct.pack("<BBH", bits, 0, current)
            code = (starter.fault_code or 0) if word & SW_FAULT else 0
            return struct.pack("<BBHH", bits, code, current, self._selected_value())

    def _selected_value(self) -> int:
        address = self.selected_address
        if address not in self._points:
            try:
                self._points[address] = self.starter.point_at(PROTOCOL, Kind.MEASUREMENT, address)
            except SimulatorRefusal as exc:
                if exc.reason is not Refusal.NOT_AVAILABLE:
                    raise
                self._points[address] = None
        point = self._points[address]
        return 0 if point is None else self.starter.read(point) & 0xFFFF

    def consume(self, instance: int, data: bytes) -> None:
        if data == self.outputs.get(instance) and self.starter.control_word == self._written:
            return  # the same outputs again: no edge, nothing to do
        output = decode_output(data, instance)
        self.outputs[instance] = bytes(data)
        if output.address is not None:
            self.selected_address = output.address
        word = output.control_word()
        self.starter.write_control_word(word, cyclic=True, source=f"DeviceNet output assembly {instance}")
        self._written = word
        self._cache.clear()

    def output_data(self, instance: int) -> bytes:
        return self.outputs.get(instance, bytes(OUTPUT_SIZES.get(instance, 0)))

    def idle(self) -> None:
        self.starter.command_lost("DeviceNet master idle (zero-length poll command)")
        self._cache.clear()

    def connection_lost(self, reason: str) -> None:
        self.starter.command_lost(reason)
        self._cache.clear()
