"""Sans-IO Modbus TCP framing: the MBAP header and the matching of answers to transactions.

An ADU is ``transaction id (2) | protocol id (2, always 0) | length (2: unit + PDU) | unit (1) | PDU``. The PDU
is the RTU frame without its unit byte and CRC, so the RTU codec (``frames.py``) encodes requests and decodes
answers. :class:`MbapEngine` numbers requests, splits the received byte stream into ADUs and says which waiting
transaction each answers: an answer whose transaction id no transaction waits for (a late answer to one that
timed out, a duplicate, another client's) is dropped and counted, never delivered as a value. Nothing here reads
a clock or does I/O.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from starterbus.core.errors import DecodeError

HEADER = struct.Struct(">HHHB")  # transaction id, protocol id, length, unit
HEADER_LENGTH = HEADER.size  # 7
MAX_PDU = 253  # Modbus application protocol: a PDU holds at most 253 bytes
PROTOCOL_ID = 0


@dataclass(frozen=True, slots=True)
class Adu:
    """One received ADU: its transaction id, unit and PDU."""

    transaction: int
    unit: int
    pdu: bytes


def encode_adu(transaction: int, unit: int, pdu: bytes) -> bytes:
    if not 1 <= len(pdu) <= MAX_PDU:
        raise ValueError(f"a PDU holds 1..{MAX_PDU} bytes, not {len(pdu)}")
    return HEADER.pack(transaction, PROTOCOL_ID, len(pdu) + 1, unit) + pdu


class MbapEngine:
    """Transaction ids and the received stream of one connection (not thread-safe: the driver locks)."""

    def __init__(self, first_id: int = 1) -> None:
        self._next = first_id & 0xFFFF
        self._buffer = bytearray()
        self.waiting: set[int] = set()
        self.stale = 0  # answers no transaction waited for: dropped
        self.stale_last = b""

    def request(self, unit: int, pdu: bytes) -> tuple[int, bytes]:
        """A new transaction: its id (one no waiting transaction holds) and the ADU to send."""
        for _ in range(0x10000):
            transaction, self._next = self._next, (self._next + 1) & 0xFFFF
            if transaction not in self.waiting:
                self.waiting.add(transaction)
                return transaction, encode_adu(transaction, unit, pdu)
        raise RuntimeError("65536 transactions waiting")  # pragma: no cover - bounded by the outstanding limit

    def forget(self, transaction: int) -> None:
        """The transaction is over (answered, or given up): an answer with its id is stale from now on."""
        self.waiting.discard(transaction)

    def feed(self, data: bytes) -> list[Adu]:
        """The ADUs ``data`` completes that answer a waiting transaction (each then no longer waits).

        Raises :class:`DecodeError` when the stream is not MBAP (protocol id not 0, a length no PDU has): the
        connection is out of step and must be closed; nothing after that point can be trusted.
        """
        self._buffer += data
        out: list[Adu] = []
        while len(self._buffer) >= HEADER_LENGTH:
            transaction, protocol, length, unit = HEADER.unpack_from(self._buffer)
            if protocol != PROTOCOL_ID or not 2 <= length <= MAX_PDU + 1:
                head = bytes(self._buffer[:HEADER_LENGTH])
                self._buffer.clear()
                raise DecodeError(
                    f"not an MBAP header (protocol id {protocol}, length {length}): the stream is out of step",
                    head,
                    "mbap",
                )
            end = HEADER_LENGTH - 1 + length
            if len(self._buffer) < end:
                break
            pdu = bytes(self._buffer[HEADER_LENGTH:end])
            raw = bytes(self._buffer[:end])
            del self._buffer[:end]
            if transaction in self.waiting:
                self.waiting.discard(transaction)
                out.append(Adu(transaction, unit, pdu))
            else:
                self.stale += 1
                self.stale_last = raw
        return out

    def reset(self) -> None:
        """A new connection: nothing received yet, nothing waiting."""
        self._buffer.clear()
        self.waiting.clear()
