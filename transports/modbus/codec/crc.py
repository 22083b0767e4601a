"""CRC-16/Modbus: polynomial 0xA001 (reflected 0x8005), initial value 0xFFFF, sent low byte first.

Table-driven: one table lookup per byte. ``crc16(b"\\x02\\x03\\x01\\x00\\x00\\x01") == 0xC585`` (sent as ``85 C5``).
"""

from __future__ import annotations

from starterbus.core import ChecksumError, DecodeError

POLYNOMIAL = 0xA001
INITIAL = 0xFFFF
CRC_LENGTH = 2


def _make_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ POLYNOMIAL if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


TABLE: tuple[int, ...] = _make_table()


def crc16(data: bytes | bytearray | memoryview, crc: int = INITIAL) -> int:
    """The CRC-16/Modbus of ``data`` as an integer (low byte goes on the wire first).

    ``crc`` continues a CRC: ``crc16(b, crc16(a)) == crc16(a + b)``.
    """
    table = TABLE
    for byte in data if isinstance(data, (bytes, bytearray)) else bytes(data):
        crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]
    return crc


def crc_bytes(data: bytes | bytearray | memoryview) -> bytes:
    """The two CRC bytes in wire order (low byte first)."""
    return crc16(data).to_bytes(2, "little")


def append_crc(body: bytes | bytearray | memoryview) -> bytes:
    """``body`` (unit id + PDU) followed by its CRC: a complete RTU frame."""
    data = bytes(body)
    return data + crc_bytes(data)


def strip_crc(frame: bytes | bytearray | memoryview) -> bytes:
    """Check a frame's CRC and return the frame without it.

    Raises :class:`ChecksumError` (naming the frame, the CRC received and the right one) when it is wrong,
    :class:`DecodeError` when the frame is too short to hold a CRC.
    """
    data = bytes(frame)
    if len(data) <= CRC_LENGTH:
        raise DecodeError(f"{len(data)} bytes cannot hold a unit id, a function code and a CRC", data, "frame")
    body, received = data[:-CRC_LENGTH], data[-CRC_LENGTH:]
    right = crc_bytes(body)
    if received != right:
        raise ChecksumError(
            f"CRC {received.hex(' ').upper()} is wrong, the right CRC is {right.hex(' ').upper()}", data, "crc"
        )
    return body
