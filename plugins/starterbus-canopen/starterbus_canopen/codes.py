"""CiA 301 codes this plugin speaks: SDO abort codes with their meanings, NMT commands and states, EMCY codes.

Pure tables and small pure codecs (PDO payloads of this plugin's design), shared by the transport, the simulator
front end and the decoder.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from starterbus.core import DecodeError, Refusal

#: CiA 301 table 22 (SDO abort codes)
ABORT_CODES: dict[int, str] = {
    0x05030000: "toggle bit not alternated",
    0x05040000: "SDO protocol timed out",
    0x05040001: "client/server command specifier not valid or unknown",
    0x05040002: "invalid block size",
    0x05040003: "invalid sequence number",
    0x05040004: "CRC error",
    0x05040005: "out of memory",
    0x06010000: "unsupported access to an object",
    0x06010001: "attempt to read a write-only object",
    0x06010002: "attempt to write a read-only object",
    0x06020000: "object does not exist in the object dictionary",
    0x06040041: "object cannot be mapped to the PDO",
    0x06040042: "the number and length of the objects to be mapped would exceed the PDO length",
    0x06040043: "general parameter incompatibility",
    0x06040047: "general internal incompatibility in the device",
    0x06060000: "access failed due to a hardware error",
    0x06070010: "data type does not match, length of service parameter does not match",
    0x06070012: "data type does not match, length of service parameter too high",
    0x06070013: "data type does not match, length of service parameter too low",
    0x06090011: "sub-index does not exist",
    0x06090030: "invalid value for parameter (download only)",
    0x06090031: "value of parameter written too high",
    0x06090032: "value of parameter written too low",
    0x06090036: "maximum value is less than minimum value",
    0x060A0023: "resource not available: SDO connection",
    0x08000000: "general error",
    0x08000020: "data cannot be transferred or stored to the application",
    0x08000021: "data cannot be transferred or stored to the application because of local control",
    0x08000022: "data cannot be transferred or stored to the application because of the present device state",
    0x08000023: "object dictionary dynamic generation fails or no object dictionary is present",
    0x08000024: "no data available",
}

#: the simulated starter's refusals as SDO aborts (design: the closest CiA 301 meaning)
REFUSAL_ABORTS: dict[Refusal, int] = {
    Refusal.NOT_AVAILABLE: 0x06020000,
    Refusal.READ_ONLY: 0x06010002,
    Refusal.OUT_OF_RANGE: 0x06090030,
    Refusal.WRITE_PROTECTED: 0x08000020,
    Refusal.WHILE_RUNNING: 0x08000022,
}


def abort_meaning(code: int) -> str:
    return ABORT_CODES.get(code, f"unknown abort code 0x{code:08X}")


NMT_COMMANDS: dict[int, str] = {
    0x01: "start remote node (operational)",
    0x02: "stop remote node (stopped)",
    0x80: "enter pre-operational",
    0x81: "reset node",
    0x82: "reset communication",
}

NMT_STATES: dict[int, str] = {0x00: "boot-up", 0x04: "stopped", 0x05: "operational", 0x7F: "pre-operational"}

#: EMCY error codes (CiA 301 table 21, the ones this plugin sends or meets most)
EMCY_CODES: dict[int, str] = {
    0x0000: "error reset or no error",
    0x1000: "generic error",
    0x2000: "current",
    0x3000: "voltage",
    0x4000: "temperature",
    0x5000: "device hardware",
    0x6000: "device software",
    0x8100: "communication",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard error or heartbeat error",
    0x8140: "recovered from bus off",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x9000: "external error",
    0xFF00: "device specific",
}

#: error register (0x1001) bits
ERROR_REGISTER_BITS = (
    "generic",
    "current",
    "voltage",
    "temperature",
    "communication",
    "device profile",
    "",
    "manufacturer",
)
ER_GENERIC = 0x01
ER_COMMUNICATION = 0x10
EMCY_HEARTBEAT = 0x8130


def emcy_meaning(code: int) -> str:
    if code in EMCY_CODES:
        return EMCY_CODES[code]
    return EMCY_CODES.get(code & 0xFF00, EMCY_CODES.get(code & 0xF000, "unknown error code"))


# -- PDO set 1 of this plugin's design ---------------------------------------------------------------------------

TPDO1_BASE = 0x180
RPDO1_BASE = 0x200


@dataclass(frozen=True, slots=True)
class Tpdo1:
    """TPDO1 (design): status word, phase A current raw (both UNSIGNED16, little endian)."""

    status_word: int
    current_raw: int

    def encode(self) -> bytes:
        return struct.pack("<HH", self.status_word, self.current_raw)

    @classmethod
    def decode(cls, data: bytes) -> Tpdo1:
        if len(data) != 4:
            raise DecodeError(f"TPDO1 has {len(data)} bytes, expected 4 (status word, phase A current)", data, "TPDO1")
        status, current = struct.unpack("<HH", data)
        return cls(status, current)


def encode_rpdo1(control_word: int) -> bytes:
    """RPDO1 (design): the control word, UNSIGNED16 little endian."""
    return struct.pack("<H", control_word)


def decode_rpdo1(data: bytes) -> int:
    if len(data) != 2:
        raise DecodeError(f"RPDO1 has {len(data)} bytes, expected 2 (control word)", data, "RPDO1")
    return int(struct.unpack("<H", data)[0])
