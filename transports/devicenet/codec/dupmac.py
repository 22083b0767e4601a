"""Duplicate MAC ID check messages (group 2 message id 7, on the sender's own MAC).

Seven data bytes: ``[request/response << 7 | physical port][vendor id, little-endian][serial number, LE32]``.
A node going on line sends a request, waits (1 s per the specification), sends it again, waits again, and
is on line if nobody answered; an on-line node answers a request for its MAC with a response.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from starterbus.core import CanFrame, EncodeError
from starterbus.transports.devicenet.codec.cip import FrameTooLongError, FrameTooShortError, UnexpectedFrameError
from starterbus.transports.devicenet.codec.ids import Group, Group2, duplicate_mac_id, parse_id

DUP_MAC_LENGTH = 7
RESPONSE_FLAG = 0x80
DEFAULT_WAIT = 1.0  # seconds between the two requests and after the second (DeviceNet specification)


@dataclass(frozen=True, slots=True)
class DuplicateMacCheck:
    mac: int
    response: bool
    vendor_id: int
    serial_number: int
    port: int = 0

    def data(self) -> bytes:
        if not 0 <= self.port <= 0x7F:
            raise EncodeError(f"physical port {self.port} is outside 0..127", field="port")
        if not 0 <= self.vendor_id <= 0xFFFF or not 0 <= self.serial_number <= 0xFFFFFFFF:
            raise EncodeError("vendor id must be 16 bits and serial number 32 bits", field="identity")
        return struct.pack(
            "<BHI", (RESPONSE_FLAG if self.response else 0) | self.port, self.vendor_id, self.serial_number
        )

    def frame(self) -> CanFrame:
        return CanFrame(duplicate_mac_id(self.mac), self.data())

    def describe(self) -> str:
        kind = "response" if self.response else "request"
        return (
            f"duplicate MAC ID check {kind} for MAC {self.mac}: vendor {self.vendor_id}, "
            f"serial 0x{self.serial_number:08X}"
        )


def is_duplicate_mac(frame: CanFrame) -> bool:
    return 0x400 <= frame.can_id < 0x600 and frame.can_id & 0x07 == Group2.DUPLICATE_MAC_CHECK


def decode_duplicate_mac(frame: CanFrame) -> DuplicateMacCheck:
    ident = parse_id(frame.can_id)
    if ident.group is not Group.GROUP_2 or ident.message_id != Group2.DUPLICATE_MAC_CHECK or ident.mac is None:
        raise UnexpectedFrameError(
            f"identifier 0x{frame.can_id:03X} is not a duplicate MAC ID check", frame.data, "can_id"
        )
    if len(frame.data) < DUP_MAC_LENGTH:
        raise FrameTooShortError(
            f"duplicate MAC ID check needs 7 bytes, got {len(frame.data)}", frame.data, "duplicate_mac"
        )
    if len(frame.data) > DUP_MAC_LENGTH:
        raise FrameTooLongError(
            f"duplicate MAC ID check needs 7 bytes, got {len(frame.data)}", frame.data, "duplicate_mac"
        )
    flags, vendor, serial = struct.unpack("<BHI", frame.data)
    return DuplicateMacCheck(ident.mac, bool(flags & RESPONSE_FLAG), vendor, serial, flags & 0x7F)
