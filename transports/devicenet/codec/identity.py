"""The Identity object (class 0x01) attributes, encoded and decoded the same way by slave and master.

1 vendor id UINT, 2 device type UINT, 3 product code UINT, 4 revision {USINT major, USINT minor},
5 status WORD, 6 serial number UDINT, 7 product name SHORT_STRING (length byte + characters); all little-endian.
The JJR8000's product name "JJR8000" makes attribute 7's response 10 bytes long: it is fragmented.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass, replace

from starterbus.core import EncodeError
from starterbus.transports.devicenet.codec.cip import FrameTooLongError, FrameTooShortError

ATTRIBUTE_NAMES: dict[int, str] = {
    1: "vendor_id",
    2: "device_type",
    3: "product_code",
    4: "revision",
    5: "status",
    6: "serial_number",
    7: "product_name",
}
_FIXED_SIZES = {1: 2, 2: 2, 3: 2, 4: 2, 5: 2, 6: 4}

# Identity status word bits (CIP): only "owned" is used by the JJR8000 simulator.
STATUS_OWNED = 0x0001
STATUS_CONFIGURED = 0x0004


@dataclass(frozen=True, slots=True)
class Identity:
    vendor_id: int = 819
    device_type: int = 45
    product_code: int = 1
    revision: tuple[int, int] = (1, 1)
    status: int = 0
    serial_number: int = 0x20110100
    product_name: str = ""  # settings.profile_identity: the profile's, else its display name

    def __post_init__(self) -> None:
        for name, value, hi in (
            ("vendor_id", self.vendor_id, 0xFFFF),
            ("device_type", self.device_type, 0xFFFF),
            ("product_code", self.product_code, 0xFFFF),
            ("status", self.status, 0xFFFF),
            ("serial_number", self.serial_number, 0xFFFFFFFF),
        ):
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= hi:
                raise EncodeError(f"{value!r} is outside 0..{hi}", field=f"identity.{name}")
        if len(self.revision) != 2 or not all(0 <= v <= 0xFF for v in self.revision):
            raise EncodeError(f"revision {self.revision!r} is not (major, minor) bytes", field="identity.revision")
        encoded = self.product_name.encode("ascii", errors="replace")
        if len(encoded) > 32:
            raise EncodeError("product name longer than 32 characters", encoded, "identity.product_name")

    def with_status(self, status: int) -> Identity:
        return replace(self, status=status)

    def attribute(self, number: int) -> bytes | None:
        """Attribute ``number`` as sent on the wire, or None if the object has no such attribute."""
        if number == 1:
            return struct.pack("<H", self.vendor_id)
        if number == 2:
            return struct.pack("<H", self.device_type)
        if number == 3:
            return struct.pack("<H", self.product_code)
        if number == 4:
            return bytes(self.revision)
        if number == 5:
            return struct.pack("<H", self.status)
        if number == 6:
            return struct.pack("<I", self.serial_number)
        if number == 7:
            name = self.product_name.encode("ascii", errors="replace")
            return bytes((len(name),)) + name
        return None

    def attributes_all(self) -> bytes:
        """Get_Attributes_All: attributes 1-7 back to back."""
        return b"".join(self.attribute(n) or b"" for n in range(1, 8))

    def as_dict(self) -> dict[str, object]:
        return {
            "vendor_id": self.vendor_id,
            "device_type": self.device_type,
            "product_code": self.product_code,
            "revision": f"{self.revision[0]}.{self.revision[1]}",
            "status": f"0x{self.status:04X}",
            "serial_number": f"0x{self.serial_number:08X}",
            "product_name": self.product_name,
        }


def _name(number: int) -> str:
    return ATTRIBUTE_NAMES.get(number, f"attribute {number}")


def _exact(number: int, data: bytes, size: int) -> None:
    if len(data) < size:
        raise FrameTooShortError(f"{_name(number)} needs {size} bytes, got {len(data)}", data, _name(number))
    if len(data) > size:
        raise FrameTooLongError(f"{_name(number)} needs {size} bytes, got {len(data)}", data, _name(number))


def decode_uint(number: int, data: bytes) -> int:
    """A fixed-size unsigned attribute (1, 2, 3, 5, 6), exact length required."""
    _exact(number, data, _FIXED_SIZES.get(number, len(data)))
    return int.from_bytes(data, "little")


def decode_revision(data: bytes) -> tuple[int, int]:
    _exact(4, data, 2)
    return data[0], data[1]


def decode_short_string(data: bytes, number: int = 7) -> str:
    """SHORT_STRING: a length byte and that many ASCII characters (exactly)."""
    name = _name(number)
    if not data:
        raise FrameTooShortError("SHORT_STRING without its length byte", data, name)
    length = data[0]
    if len(data) < 1 + length:
        raise FrameTooShortError(f"SHORT_STRING announces {length} characters, has {len(data) - 1}", data, name)
    if len(data) > 1 + length:
        raise FrameTooLongError(f"SHORT_STRING announces {length} characters, has {len(data) - 1}", data, name)
    return data[1:].decode("ascii", errors="replace")


def decode_attribute(number: int, data: bytes) -> int | str | tuple[int, int]:
    """One Identity attribute's value from its wire bytes (exact length required)."""
    if number == 7:
        return decode_short_string(data)
    if number == 4:
        return decode_revision(data)
    return decode_uint(number, data)


def decode_identity(attributes: Mapping[int, bytes]) -> Identity:
    """An :class:`Identity` from the raw bytes of attributes 1-7 (missing ones are 0 / empty)."""

    def uint(number: int) -> int:
        return decode_uint(number, attributes[number]) if number in attributes else 0

    return Identity(
        vendor_id=uint(1),
        device_type=uint(2),
        product_code=uint(3),
        revision=decode_revision(attributes[4]) if 4 in attributes else (0, 0),
        status=uint(5),
        serial_number=uint(6),
        product_name=decode_short_string(attributes[7]) if 7 in attributes else "",
    )
