"""Modbus RTU messages as these soft starters speak them: FC03 and FC06 requests, responses and exceptions; and
what a register gateway adds (FC04 reads, FC16 writes: a Profibus gateway's images, docs/profibus.md).

Frozen dataclasses, no I/O. A frame is ``unit id + PDU + CRC``; :meth:`encode` gives the whole frame. Decoding a
frame into these, and checking an answer against its request, is :mod:`.decoding`.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import ClassVar

from starterbus.core import EncodeError
from starterbus.spaces.modbus import STANDARD_EXCEPTION_TEXTS as _STANDARD_TEXTS
from starterbus.transports.modbus.codec.crc import append_crc


class FunctionCode(enum.IntEnum):
    READ_HOLDING_REGISTERS = 0x03
    READ_INPUT_REGISTERS = 0x04
    WRITE_SINGLE_REGISTER = 0x06
    WRITE_MULTIPLE_REGISTERS = 0x10


class ExceptionCode(enum.IntEnum):
    """Exception codes these devices send; their meaning per model comes from the profile."""

    ILLEGAL_FUNCTION = 0x01
    ILLEGAL_DATA_ADDRESS = 0x02
    ILLEGAL_DATA_VALUE = 0x03
    PARAMETER_MODIFY_FORBIDDEN = 0x04  # Modbus "server device failure"; JJR5000/SSD1: "parameter modify" = 0


#: standard texts, used only when a profile does not name an exception code
STANDARD_EXCEPTION_TEXTS = dict(_STANDARD_TEXTS)

EXCEPTION_BIT = 0x80
BROADCAST = 0
MAX_UNIT = 247  # 248-255 are reserved by Modbus
MAX_READ_REGISTERS = 125  # Modbus application protocol limit for FC03
MAX_WRITE_REGISTERS = 123  # and for FC16
EXCEPTION_FRAME_LENGTH = 5  # unit, function | 0x80, code, CRC
WRITE_FRAME_LENGTH = 8  # unit, 06, address, value, CRC (request and echo)
READ_REQUEST_LENGTH = 8  # unit, 03, address, count, CRC


def _check_field(name: str, value: int, lo: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise EncodeError(f"{value!r} is outside {lo}..{hi}", field=name)


# -- requests -----------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ReadRequest:
    """FC03: read ``count`` registers from ``address`` (both data areas of these devices)."""

    unit: int
    address: int
    count: int
    function: ClassVar[int] = FunctionCode.READ_HOLDING_REGISTERS

    def __post_init__(self) -> None:
        _check_field("unit", self.unit, 0, 0xFF)
        _check_field("address", self.address, 0, 0xFFFF)
        _check_field("count", self.count, 0, 0xFFFF)

    def encode(self) -> bytes:
        if not 1 <= self.count <= MAX_READ_REGISTERS:
            raise EncodeError(
                f"{self.count} registers: FC{self.function:02d} reads 1..{MAX_READ_REGISTERS}", field="count"
            )
        if self.address + self.count - 1 > 0xFFFF:
            raise EncodeError(f"{self.count} registers from {self.address:#06x} pass 0xFFFF", field="count")
        return append_crc(
            bytes((self.unit, self.function)) + self.address.to_bytes(2, "big") + self.count.to_bytes(2, "big")
        )


@dataclass(frozen=True, slots=True)
class ReadInputRequest(ReadRequest):
    """FC04: read ``count`` input registers from ``address`` (a gateway's input image; the FC03 layout)."""

    function: ClassVar[int] = FunctionCode.READ_INPUT_REGISTERS


@dataclass(frozen=True, slots=True)
class _SingleRegister:
    """The FC06 layout, shared by the request and its echo (they differ only in type)."""

    unit: int
    address: int
    value: int
    function: ClassVar[int] = FunctionCode.WRITE_SINGLE_REGISTER

    def __post_init__(self) -> None:
        _check_field("unit", self.unit, 0, 0xFF)
        _check_field("address", self.address, 0, 0xFFFF)
        _check_field("value", self.value, 0, 0xFFFF)

    def encode(self) -> bytes:
        return append_crc(
            bytes((self.unit, self.function)) + self.address.to_bytes(2, "big") + self.value.to_bytes(2, "big")
        )


@dataclass(frozen=True, slots=True)
class WriteRequest(_SingleRegister):
    """FC06: write ``value`` to the register ``address``."""


@dataclass(frozen=True, slots=True)
class OtherRequest:
    """A request with a function code these devices do not support (a slave answers exception 01)."""

    unit: int
    function: int
    data: bytes = b""

    def __post_init__(self) -> None:
        _check_field("unit", self.unit, 0, 0xFF)
        _check_field("function", self.function, 1, 0x7F)
        if self.function in (FunctionCode.READ_HOLDING_REGISTERS, FunctionCode.WRITE_SINGLE_REGISTER):
            raise EncodeError(f"function {self.function:#04x} has its own request class", field="function")

    def encode(self) -> bytes:
        return append_crc(bytes((self.unit, self.function)) + self.data)


@dataclass(frozen=True, slots=True)
class WriteRegistersRequest:
    """FC16: write ``values`` to the registers from ``address`` on (a gateway's output image)."""

    unit: int
    address: int
    values: tuple[int, ...]
    function: ClassVar[int] = FunctionCode.WRITE_MULTIPLE_REGISTERS

    def __post_init__(self) -> None:
        _check_field("unit", self.unit, 0, 0xFF)
        _check_field("address", self.address, 0, 0xFFFF)
        for i, value in enumerate(self.values):
            _check_field(f"values[{i}]", value, 0, 0xFFFF)

    def encode(self) -> bytes:
        count = len(self.values)
        if not 1 <= count <= MAX_WRITE_REGISTERS:
            raise EncodeError(f"{count} registers: FC16 writes 1..{MAX_WRITE_REGISTERS}", field="values")
        if self.address + count - 1 > 0xFFFF:
            raise EncodeError(f"{count} registers from {self.address:#06x} pass 0xFFFF", field="values")
        head = bytes((self.unit, self.function)) + self.address.to_bytes(2, "big") + count.to_bytes(2, "big")
        return append_crc(head + bytes((2 * count,)) + b"".join(v.to_bytes(2, "big") for v in self.values))


Request = ReadRequest | WriteRequest | WriteRegistersRequest
AnyRequest = ReadRequest | WriteRequest | OtherRequest  # what a starter takes (FC04, FC16: other requests)


# -- responses ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ReadResponse:
    """FC03 answer: the register values, in order."""

    unit: int
    values: tuple[int, ...]
    function: ClassVar[int] = FunctionCode.READ_HOLDING_REGISTERS

    def __post_init__(self) -> None:
        _check_field("unit", self.unit, 0, 0xFF)
        if not 1 <= len(self.values) <= 127:
            raise EncodeError(f"{len(self.values)} values: a FC03 answer holds 1..127 registers", field="values")
        for i, value in enumerate(self.values):
            _check_field(f"values[{i}]", value, 0, 0xFFFF)

    @classmethod
    def from_words(cls, unit: int, words: tuple[int, ...]) -> ReadResponse:
        """The answer decoded from a frame: ``unit`` is a byte and ``words`` are 1..127 unpacked 16-bit words,
        so the constructor's checks cannot fail (skipping them is most of the cost of building the value)."""
        response = object.__new__(cls)
        object.__setattr__(response, "unit", unit)
        object.__setattr__(response, "values", words)
        return response

    def encode(self) -> bytes:
        payload = b"".join(v.to_bytes(2, "big") for v in self.values)
        return append_crc(bytes((self.unit, self.function, len(payload))) + payload)


@dataclass(frozen=True, slots=True)
class ReadInputResponse(ReadResponse):
    """FC04 answer: the input register values, in order."""

    function: ClassVar[int] = FunctionCode.READ_INPUT_REGISTERS


@dataclass(frozen=True, slots=True)
class WriteResponse(_SingleRegister):
    """FC06 answer: the echo of the request."""


@dataclass(frozen=True, slots=True)
class WriteRegistersResponse:
    """FC16 answer: where the registers were written and how many."""

    unit: int
    address: int
    count: int
    function: ClassVar[int] = FunctionCode.WRITE_MULTIPLE_REGISTERS

    def __post_init__(self) -> None:
        _check_field("unit", self.unit, 0, 0xFF)
        _check_field("address", self.address, 0, 0xFFFF)
        _check_field("count", self.count, 0, 0xFFFF)

    def encode(self) -> bytes:
        return append_crc(
            bytes((self.unit, self.function)) + self.address.to_bytes(2, "big") + self.count.to_bytes(2, "big")
        )


@dataclass(frozen=True, slots=True)
class ExceptionResponse:
    """The device refused: ``function`` is the request's function code (without the 0x80 bit)."""

    unit: int
    function: int
    code: int

    def __post_init__(self) -> None:
        _check_field("unit", self.unit, 0, 0xFF)
        _check_field("function", self.function, 1, 0x7F)
        _check_field("code", self.code, 0, 0xFF)

    def encode(self) -> bytes:
        return append_crc(bytes((self.unit, self.function | EXCEPTION_BIT, self.code)))


Response = ReadResponse | WriteResponse | WriteRegistersResponse | ExceptionResponse
