"""Sans-IO Modbus TCP framing: the MBAP header and the matching of answers to transactions.

An ADU is ``transaction id (2) | protocol id (2, always 0) | length (2: unit + PDU) | unit (1) | PDU``. The PDU
is the RTU frame without its unit byte and CRC, so the RTU codec (``codec/messages.py``, ``codec/decoding.py``)
encodes requests and decodes answers. :class:`MbapEngine` numbers requests, splits the received byte stream into
ADUs and says which waiting transaction each answers: an answer whose transaction id no transaction waits for (a
late answer to one that timed out, a duplicate, another client's) is dropped and counted, never delivered as a
value. Nothing here reads a clock or does I/O.

It is also the connection's :class:`~starterbus.core.engine.Engine` (docs/engine.md): a prepared
:class:`~starterbus.transports.modbus.master.exchange.Exchange` submitted is a :class:`MbapTicket`, sent when one of
``outstanding`` slots is free, numbered at the send. An answer with its id is checked against the request (unit,
then the RTU codec's checks); the gateway's 0x0A / 0x0B say the device behind it is unreachable. A timeout, a
wrong answer or 0x0A / 0x0B is a failed attempt, sent again (a new id) within the exchange's attempts; a
timed-out id is forgotten, so its late answer is stale. A stream that is not MBAP marks the engine ``broken``:
the driver drops the connection (:meth:`MbapEngine.lost`).
"""

from __future__ import annotations

import struct
from collections import deque
from dataclasses import dataclass

from starterbus.core import FOREVER, DecodeError, StarterbusError, Ticket, TimeoutError
from starterbus.spaces.modbus import GATEWAY_EXCEPTIONS, STANDARD_EXCEPTION_TEXTS
from starterbus.transports.modbus.codec.decoding import decode_response
from starterbus.transports.modbus.codec.messages import ExceptionResponse, Response
from starterbus.transports.modbus.master.exchange import Exchange

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


@dataclass(eq=False, slots=True)
class MbapTicket(Ticket[Exchange, Response]):
    """A transaction's ticket: the id of its latest send, the bytes of the answer (MBAP header + PDU)."""

    transaction: int = -1
    received: int = 0


class MbapEngine:
    """Transaction ids and the received stream of one connection; the connection's engine (one caller at a
    time: the scheduler's leader). ``name``: the connection, in messages."""

    def __init__(self, first_id: int = 1, outstanding: int = 1, name: str = "") -> None:
        self._next = first_id & 0xFFFF
        self._buffer = bytearray()
        self.waiting: set[int] = set()
        self.stale = 0  # answers no transaction waited for: dropped
        self.stale_last = b""
        self.outstanding = outstanding
        self.name = name
        self.broken: str | None = None
        self._queue: deque[MbapTicket] = deque()
        self._sent: dict[int, tuple[MbapTicket, float]] = {}  # id -> ticket, its answer's deadline
        self._done: list[MbapTicket] = []

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

    # -- the Engine surface ---------------------------------------------------------------------------------

    @property
    def deadline(self) -> float:
        if not self._sent:
            return FOREVER
        return min(at for _, at in self._sent.values())

    @property
    def pending(self) -> int:
        return len(self._queue) + len(self._sent)

    def submit(self, request: Exchange, now: float) -> MbapTicket:
        ticket = MbapTicket(request)
        self._queue.append(ticket)
        return ticket

    def cancel(self, ticket: Ticket[Exchange, Response], now: float) -> None:
        if ticket.ended:
            return
        if ticket in self._queue:
            self._queue.remove(ticket)  # type: ignore[arg-type]  # only MbapTickets are queued
        elif isinstance(ticket, MbapTicket) and ticket.transaction in self._sent:
            del self._sent[ticket.transaction]
            self.forget(ticket.transaction)  # its answer is stale from now on
        ticket.cancelled(now)
        self._done.append(ticket)  # type: ignore[arg-type]

    def receive(self, data: bytes | None, now: float) -> None:
        if not data:
            return
        try:
            adus = self.feed(data)
        except DecodeError as exc:
            self.broken = str(exc)
            return
        for adu in adus:
            entry = self._sent.pop(adu.transaction, None)
            if entry is None:  # numbered by request() alone, outside the engine's transactions
                self.stale += 1
                continue
            self._answered(entry[0], adu, now)

    def advance(self, now: float) -> None:
        for transaction, (ticket, at) in list(self._sent.items()):
            if at <= now:
                del self._sent[transaction]
                self.forget(transaction)
                exchange = ticket.request
                self._attempt_failed(
                    ticket,
                    TimeoutError(
                        f"{self.name}: no answer from unit {exchange.request.unit} within "
                        f"{exchange.policy.timeout:g} s (transaction {transaction})"
                    ),
                    now,
                )

    def take_output(self, now: float) -> list[bytes]:
        out: list[bytes] = []
        while self._queue and len(self._sent) < self.outstanding:
            ticket = self._queue.popleft()
            exchange = ticket.request
            transaction, adu = self.request(exchange.request.unit, exchange.frame[1:-2])
            ticket.sent(now)
            ticket.transaction = transaction
            self._sent[transaction] = (ticket, now + exchange.policy.timeout)
            out.append(adu)
        return out

    def take_completed(self) -> list[MbapTicket]:
        done, self._done = self._done, []
        return done

    def lost(self, error: StarterbusError, now: float) -> None:
        """The connection is gone: every sent transaction fails; the queued ones wait for the next."""
        for ticket, _ in self._sent.values():
            ticket.failed(error, now)
            self._done.append(ticket)
        self._sent.clear()
        self.reset()
        self.broken = None

    def refuse(self, error: StarterbusError, now: float) -> None:
        """No connection now: every queued transaction fails."""
        while self._queue:
            ticket = self._queue.popleft()
            ticket.failed(error, now)
            self._done.append(ticket)

    def _answered(self, ticket: MbapTicket, adu: Adu, now: float) -> None:
        request = ticket.request.request
        try:
            if adu.unit != request.unit:
                raise DecodeError(
                    f"answer from unit {adu.unit} to transaction {adu.transaction}, which went to unit {request.unit}",
                    adu.pdu,
                    "unit",
                )
            response = decode_response(bytes((adu.unit,)) + adu.pdu, crc=False, request=request)
            if isinstance(response, ExceptionResponse) and response.code in GATEWAY_EXCEPTIONS:
                raise TimeoutError(
                    f"{self.name}: the device behind the gateway is unreachable: unit {adu.unit}, exception "
                    f"0x{response.code:02X} ({STANDARD_EXCEPTION_TEXTS[response.code]})"
                )
        except (TimeoutError, DecodeError) as exc:
            self._attempt_failed(ticket, exc, now)
            return
        ticket.received = HEADER_LENGTH + len(adu.pdu)
        ticket.done(response, now)
        self._done.append(ticket)

    def _attempt_failed(self, ticket: MbapTicket, error: StarterbusError, now: float) -> None:
        """Sent again first (a new id) within the exchange's attempts; then the ticket fails, saying so."""
        exchange = ticket.request
        if ticket.attempts < exchange.attempts:
            self._queue.appendleft(ticket)
            return
        note = f" (attempt {ticket.attempts} of {exchange.attempts}"
        note += ")" if exchange.may_retry else "; a write is not repeated unless retry_writes=1)"
        error.args = (str(error) + note,)
        ticket.failed(error, now)
        self._done.append(ticket)
