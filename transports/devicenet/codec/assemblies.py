"""The JJR8000 I/O assemblies (manual section 3.2.4/3.3.5) and their mapping to the neutral status and commands.

Input (slave -> master, little-endian)::

    instance 1   (4 bytes)  [bits][reserved][L1 current in A, 2 bytes]
    instance 101 (6 bytes)  [bits][fault/warning code][L1 current in A, 2 bytes][selected status parameter, 2 bytes]
    bits: 0 fault/trip, 1 warning, 2 running, 3 starting, 4 soft stopping, 5 network control,
          6 reserved, 7 at reference (instance 1 only; reserved in 101)

Output (master -> slave)::

    instance 2   (1 byte)   [bits]                   bit 0 start (1) / stop (0), bit 2 fault reset
    instance 102 (2 bytes)  [bits][status parameter address (appendix 2) to report in input bytes 4-5]

The phase current in an input assembly has a resolution of 1 A (the manual: "unit A"), unlike the 0.1 A
measurement of Modbus/Profibus: the decoded :class:`~starterbus.core.model.Value` says so (resolution 1.0).
"""

from __future__ import annotations

import enum
import struct
import time
from dataclasses import dataclass

from starterbus.core import CW_BUS_CONTROL, CW_RESET, CW_START, EncodeError, PointDef, Profile, Status, Value
from starterbus.transports.devicenet.codec.cip import FrameTooLongError, FrameTooShortError, UnexpectedFrameError

CURRENT_RESOLUTION_A = 1.0
SOURCE = "devicenet"


class InputBit(enum.IntFlag):
    FAULT = 0x01
    WARNING = 0x02
    RUNNING = 0x04
    STARTING = 0x08
    STOPPING = 0x10
    NETWORK_CONTROL = 0x20
    RESERVED_6 = 0x40
    AT_REFERENCE = 0x80  # instance 1 only


class OutputBit(enum.IntFlag):
    START = 0x01
    FAULT_RESET = 0x04


OUTPUT_KNOWN = int(OutputBit.START | OutputBit.FAULT_RESET)
INPUT_BIT_NAMES = {
    InputBit.FAULT: "fault/trip",
    InputBit.WARNING: "warning",
    InputBit.RUNNING: "running",
    InputBit.STARTING: "starting",
    InputBit.STOPPING: "soft stopping",
    InputBit.NETWORK_CONTROL: "network control",
    InputBit.RESERVED_6: "reserved bit 6",
    InputBit.AT_REFERENCE: "at reference",
}


class AssemblySet(str, enum.Enum):
    """PRO type P1/M1 = basic (1/2), P3/M2 = extended (101/102)."""

    BASIC = "basic"
    EXTENDED = "extended"

    @property
    def input_instance(self) -> int:
        return 1 if self is AssemblySet.BASIC else 101

    @property
    def output_instance(self) -> int:
        return 2 if self is AssemblySet.BASIC else 102

    @property
    def input_size(self) -> int:
        return INPUT_SIZES[self.input_instance]

    @property
    def output_size(self) -> int:
        return OUTPUT_SIZES[self.output_instance]

    @classmethod
    def for_sizes(cls, produced: int, consumed: int) -> AssemblySet | None:
        for choice in cls:
            if choice.input_size == produced and choice.output_size == consumed:
                return choice
        return None


INPUT_SIZES = {1: 4, 101: 6}
OUTPUT_SIZES = {2: 1, 102: 2}


def _check(name: str, value: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= hi:
        raise EncodeError(f"{value!r} is outside 0..{hi}", field=name)


@dataclass(frozen=True, slots=True)
class InputAssembly:
    """Input assembly 1 or 101 as raw fields (``code``/``selected_value`` are None for instance 1)."""

    instance: int
    bits: int
    current_a: int
    code: int | None = None
    selected_value: int | None = None
    reserved: int = 0  # byte 1 of instance 1

    def encode(self) -> bytes:
        _check("bits", self.bits, 0xFF)
        _check("current", self.current_a, 0xFFFF)
        if self.instance == 1:
            _check("reserved", self.reserved, 0xFF)
            return struct.pack("<BBH", self.bits, self.reserved, self.current_a)
        if self.instance == 101:
            code = self.code or 0
            value = self.selected_value or 0
            _check("code", code, 0xFF)
            _check("selected_value", value, 0xFFFF)
            return struct.pack("<BBHH", self.bits, code, self.current_a, value)
        raise EncodeError(f"input assembly {self.instance} is not 1 or 101", field="instance")

    def flag(self, bit: InputBit) -> bool:
        return bool(self.bits & bit)

    def bit_names(self) -> list[str]:
        names = []
        for bit, name in INPUT_BIT_NAMES.items():
            if self.bits & bit:
                reserved = bit is InputBit.AT_REFERENCE and self.instance != 1
                names.append("reserved bit 7" if reserved else name)
        return names

    def to_status(
        self,
        profile: Profile,
        *,
        selected_address: int | None = None,
        timestamp: float | None = None,
        source: str = SOURCE,
    ) -> Status:
        """The neutral status. ``ready`` is None (no assembly reports it); at reference only from instance 1;
        the fault code only from instance 101 (instance 1 reports a fault without its code)."""
        fault = self.flag(InputBit.FAULT)
        fault_code: int | None = None
        fault_text: str | None = None
        if fault:
            if self.instance == 101 and self.code:
                fault_code = self.code
                fault_text = profile.faults.text(self.code)
            elif self.instance == 101:
                fault_text = "fault (code 0 reported)"
            else:
                fault_text = "fault (input assembly 1 does not report the code)"
        currents: dict[str, Value] = {}
        phases = profile.phase_currents()
        if phases:
            currents["a"] = Value.from_raw(phases[0], self.current_a, CURRENT_RESOLUTION_A, source)
        raw = {"input_assembly": self.instance, "status_bits": self.bits, "current_l1": self.current_a}
        if self.instance == 101:
            raw["fault_code"] = self.code or 0
            raw["selected_value"] = self.selected_value or 0
            if selected_address is not None:
                raw["selected_address"] = selected_address
        else:
            raw["reserved_byte"] = self.reserved
        unknown = self.bits & InputBit.RESERVED_6
        if self.instance != 1:
            unknown |= self.bits & InputBit.AT_REFERENCE
        return Status(
            fault=fault,
            fault_code=fault_code,
            fault_text=fault_text,
            starting=self.flag(InputBit.STARTING),
            running=self.flag(InputBit.RUNNING),
            stopping=self.flag(InputBit.STOPPING),
            ready=None,
            bus_control=self.flag(InputBit.NETWORK_CONTROL),
            warning=self.flag(InputBit.WARNING),
            at_reference=self.flag(InputBit.AT_REFERENCE) if self.instance == 1 else None,
            mains_voltage=None,
            currents=currents,
            raw=raw,
            unknown_bits=int(unknown),
            source=source,
            timestamp=time.time() if timestamp is None else timestamp,
        )


def _sized(data: bytes, instance: int, sizes: dict[int, int], what: str) -> None:
    size = sizes[instance]
    if len(data) < size:
        raise FrameTooShortError(f"{what} assembly {instance} needs {size} bytes, got {len(data)}", data, "assembly")
    if len(data) > size:
        raise FrameTooLongError(f"{what} assembly {instance} needs {size} bytes, got {len(data)}", data, "assembly")


def decode_input(data: bytes, instance: int | None = None) -> InputAssembly:
    """Decode input assembly ``instance`` (1 or 101); with None, the length decides (4 -> 1, 6 -> 101)."""
    if instance is None:
        by_size = {size: inst for inst, size in INPUT_SIZES.items()}
        if len(data) not in by_size:
            error = FrameTooShortError if len(data) < 6 else FrameTooLongError
            raise error(f"{len(data)} bytes are neither input assembly 1 (4) nor 101 (6)", data, "assembly")
        instance = by_size[len(data)]
    if instance not in INPUT_SIZES:
        raise UnexpectedFrameError(f"input assembly {instance} is not 1 or 101", data, "instance")
    _sized(data, instance, INPUT_SIZES, "input")
    if instance == 1:
        bits, reserved, current = struct.unpack("<BBH", data)
        return InputAssembly(1, bits, current, reserved=reserved)
    bits, code, current, value = struct.unpack("<BBHH", data)
    return InputAssembly(101, bits, current, code, value)


@dataclass(frozen=True, slots=True)
class OutputAssembly:
    """Output assembly 2 or 102 (``address`` None for instance 2)."""

    instance: int
    bits: int
    address: int | None = None

    def encode(self) -> bytes:
        _check("bits", self.bits, 0xFF)
        if self.instance == 2:
            return bytes((self.bits,))
        if self.instance == 102:
            address = self.address or 0
            _check("address", address, 0xFF)
            return bytes((self.bits, address))
        raise EncodeError(f"output assembly {self.instance} is not 2 or 102", field="instance")

    @property
    def start(self) -> bool:
        return bool(self.bits & OutputBit.START)

    @property
    def fault_reset(self) -> bool:
        return bool(self.bits & OutputBit.FAULT_RESET)

    def control_word(self) -> int:
        """The control word the slave applies: start and reset bits, plus bit 3 (bus control), because
        DeviceNet is the network control path and the JJR8000 only obeys commands with bit 3 set."""
        return (self.bits & OUTPUT_KNOWN) | CW_BUS_CONTROL

    def bit_names(self) -> list[str]:
        names = ["start" if self.start else "stop"]
        if self.fault_reset:
            names.append("fault reset")
        reserved = self.bits & ~OUTPUT_KNOWN & 0xFF
        if reserved:
            names.append(f"reserved bits 0x{reserved:02X}")
        return names


def decode_output(data: bytes, instance: int | None = None) -> OutputAssembly:
    """Decode output assembly ``instance`` (2 or 102); with None, the length decides (1 -> 2, 2 -> 102)."""
    if instance is None:
        by_size = {size: inst for inst, size in OUTPUT_SIZES.items()}
        if len(data) not in by_size:
            error = FrameTooShortError if not data else FrameTooLongError
            raise error(f"{len(data)} bytes are neither output assembly 2 (1) nor 102 (2)", data, "assembly")
        instance = by_size[len(data)]
    if instance not in OUTPUT_SIZES:
        raise UnexpectedFrameError(f"output assembly {instance} is not 2 or 102", data, "instance")
    _sized(data, instance, OUTPUT_SIZES, "output")
    if instance == 2:
        return OutputAssembly(2, data[0])
    return OutputAssembly(102, data[0], data[1])


def output_for_word(word: int, instance: int, address: int | None = None) -> OutputAssembly:
    """The output assembly carrying a core control word (bit 0 start, bit 2 reset; bit 3 is implicit)."""
    bits = 0
    if word & CW_START:
        bits |= OutputBit.START
    if word & CW_RESET:
        bits |= OutputBit.FAULT_RESET
    return OutputAssembly(instance, int(bits), address if instance == 102 else None)


def current_point(profile: Profile) -> PointDef | None:
    phases = profile.phase_currents()
    return phases[0] if phases else None
