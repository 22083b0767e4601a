"""The SDO client of one CANopen node, sans-IO: the core engine surface (docs/engine.md, step 7).

A request is an :class:`Upload` or a :class:`Download`, run as an expedited transfer (request ``0x600 + node``,
response ``0x580 + node``), one at a time in the order submitted. A ticket ends with the uploaded bytes (an
upload) or ``b""`` (a download), or fails: an abort from the node is a ``RemoteDeviceError("CANopen SDO", code,
meaning)``; a segmented upload offered by the node (a value over 4 bytes) is aborted and refused with
:class:`SegmentedTransferError`, as is a download of more than 4 bytes before anything is sent; no answer within
the request's timeout is a ``TimeoutError``, and the transfer is aborted on the bus (0x05040000).

SDO carries no transaction id. A response is taken only for the transfer under way and only with that transfer's
index and subindex. After a transfer that ended without its answer (a timeout, a cancellation after the send, an
unexpected response) the engine sends the node nothing for one timeout (its *quiet period*) and drops what the
node answers meanwhile (:attr:`SdoEngine.stale`): the timed-out transfer's late reply is never the next one's
value. A response the node repeats, or one that comes later than that, cannot be told from an answer.

TPDO1 (``0x180 + node``) is kept, the latest with the time it was received (:attr:`SdoEngine.tpdo`); a malformed
one is counted (:attr:`SdoEngine.bad_tpdos`) and dropped.

The engine reads no clock and does no I/O: a driver (the process's CAN driver of the bus) gives it the frames it
``wanted`` and the time, and writes what it gives.
"""

from __future__ import annotations

import math
import struct
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

from starterbus.core import (
    CanFrame,
    DecodeError,
    EncodeError,
    RemoteDeviceError,
    StarterbusError,
    Ticket,
    TimeoutError,
    UnsupportedOperationError,
)
from starterbus_canopen.codes import TPDO1_BASE, Tpdo1, abort_meaning

__all__ = [
    "ABORT_COMMAND",
    "ABORT_TIMEOUT",
    "SDO_REQUEST",
    "SDO_RESPONSE",
    "Download",
    "SdoEngine",
    "SdoRequest",
    "SdoTicket",
    "SegmentedTransferError",
    "Upload",
    "abort_frame",
    "request_frame",
]

SDO_REQUEST = 0x600  # client -> server, + node
SDO_RESPONSE = 0x580  # server -> client, + node
ABORT_TIMEOUT = 0x05040000  # "SDO protocol timed out": what the client sends when it gives up
ABORT_COMMAND = 0x05040001  # "command specifier not valid or unknown": a segmented transfer refused

_INITIATE_UPLOAD = 0x40
_INITIATE_DOWNLOAD = 0x20
_UPLOAD_RESPONSE = 0x40
_DOWNLOAD_RESPONSE = 0x60
_ABORT = 0x80
_EXPEDITED, _SIZE_GIVEN = 0x02, 0x01
_MUX = struct.Struct("<BHB")
FRAME_CACHE = 64  # request frames kept per engine, by request (a transport sends the same request objects again)


@dataclass(frozen=True, slots=True)
class Upload:
    """Read object ``index:sub``; ``timeout``: s for the answer; ``what``: the transfer in error messages (default:
    the engine's name, the service and the object)."""

    index: int
    sub: int
    timeout: float = 0.5
    what: str = ""


@dataclass(frozen=True, slots=True)
class Download:
    """Write ``data`` (1 to 4 bytes) to object ``index:sub``."""

    index: int
    sub: int
    data: bytes
    timeout: float = 0.5
    what: str = ""


SdoRequest = Upload | Download
SdoTicket = Ticket[SdoRequest, bytes]


class SegmentedTransferError(UnsupportedOperationError):
    """A value that needs a segmented or block SDO transfer (over 4 bytes): only expedited ones are written."""


def _mux(request: SdoRequest) -> str:
    return f"0x{request.index:04X}:{request.sub:02X}"


def request_frame(node: int, request: SdoRequest) -> CanFrame:
    """The initiate frame of an expedited transfer."""
    if isinstance(request, Upload):
        return CanFrame(SDO_REQUEST + node, _MUX.pack(_INITIATE_UPLOAD, request.index, request.sub) + bytes(4))
    size = len(request.data)
    command = _INITIATE_DOWNLOAD | (4 - size) << 2 | _EXPEDITED | _SIZE_GIVEN
    return CanFrame(SDO_REQUEST + node, _MUX.pack(command, request.index, request.sub) + request.data.ljust(4, b"\0"))


def abort_frame(node: int, index: int, sub: int, code: int) -> CanFrame:
    return CanFrame(SDO_REQUEST + node, _MUX.pack(_ABORT, index, sub) + code.to_bytes(4, "little"))


class SdoEngine:
    """SDO transfers to one node of one bus, and its TPDO1 (a :class:`~starterbus.core.CanEngine`).
    ``name``: the node in messages (``virtual/bus0 node 5``)."""

    def __init__(self, node: int, name: str = "") -> None:
        if not 1 <= node <= 127:
            raise EncodeError(f"CANopen node id {node} is not 1..127", field="node")
        self.node = node
        self.name = name or f"node {node}"
        self.wanted: frozenset[int] = frozenset({SDO_RESPONSE + node, TPDO1_BASE + node})
        self._queue: deque[SdoTicket] = deque()
        self._current: SdoTicket | None = None
        self._answer_by = math.inf
        self._quiet_until = -math.inf
        self._out: list[CanFrame] = []
        self._done: list[SdoTicket] = []
        #: id(request) -> (request, its frame): the request held, so its id is not reused while it is here
        self._frames: dict[int, tuple[SdoRequest, CanFrame]] = {}
        self.tpdo: tuple[Tpdo1, float] | None = None  #: the latest TPDO1 and when it was received
        self.bad_tpdos = 0  #: malformed TPDO1s dropped
        self.stale = 0  #: responses dropped: no transfer waited for them (the quiet period), or another object's
        self.malformed = 0  #: SDO responses too short to be read (dropped)
        self.timeouts = 0
        self.transfers = 0  #: transfers sent

    # -- the engine surface ---------------------------------------------------------------------------------------

    @property
    def deadline(self) -> float:
        if self._current is not None:
            return self._answer_by
        if self._queue:
            return self._quiet_until
        return math.inf

    @property
    def pending(self) -> int:
        return len(self._queue) + (self._current is not None)

    @property
    def quiet_until(self) -> float:
        """Until when nothing is sent to the node (after a transfer that ended without its answer)."""
        return self._quiet_until

    def submit(self, request: SdoRequest, now: float) -> SdoTicket:
        ticket: SdoTicket = Ticket(request)
        refused = self._refusal(request)
        if refused is not None:
            ticket.failed(refused, now)
            self._done.append(ticket)
        else:
            self._queue.append(ticket)
        return ticket

    def _what(self, request: SdoRequest) -> str:
        verb = "upload" if isinstance(request, Upload) else "download"
        return request.what or f"{self.name}: SDO {verb} {_mux(request)}"

    def _refusal(self, request: SdoRequest) -> StarterbusError | None:
        if not 0 <= request.index <= 0xFFFF or not 0 <= request.sub <= 0xFF:
            return EncodeError(f"{self._what(request)}: not an object index:subindex", field="index")
        if isinstance(request, Download) and not 1 <= len(request.data) <= 4:
            return SegmentedTransferError(
                f"{self._what(request)}: {len(request.data)} bytes need a segmented SDO transfer; only "
                "expedited transfers (1 to 4 bytes) are supported"
            )
        return None

    def cancel(self, ticket: SdoTicket, now: float) -> None:
        if ticket.ended:
            return
        if ticket is self._current:
            self._forget(now)
        elif ticket in self._queue:
            self._queue.remove(ticket)
        else:
            return
        ticket.cancelled(now)
        self._done.append(ticket)

    def receive(self, data: CanFrame | None, now: float) -> None:
        if data is None:
            return
        if data.can_id == TPDO1_BASE + self.node:
            try:
                self.tpdo = (Tpdo1.decode(data.data), now)
            except DecodeError:  # a malformed TPDO never yields a value
                self.bad_tpdos += 1
        elif data.can_id == SDO_RESPONSE + self.node:
            self._response(data.data, now)

    def advance(self, now: float) -> None:
        ticket = self._current
        if ticket is not None and now >= self._answer_by:
            request = ticket.request
            self.timeouts += 1
            self._out.append(abort_frame(self.node, request.index, request.sub, ABORT_TIMEOUT))
            self._forget(now)
            error = TimeoutError(f"{self._what(request)}: no SDO answer in {request.timeout:g} s")
            self._end(ticket, now, error=error)

    def take_output(self, now: float) -> Sequence[CanFrame]:
        if self._current is None and self._queue and now >= self._quiet_until:
            ticket = self._queue.popleft()
            ticket.sent(now)
            self.transfers += 1
            self._current = ticket
            self._answer_by = now + ticket.request.timeout
            request = ticket.request
            kept = self._frames.get(id(request))
            if kept is not None and kept[0] is request:
                frame = kept[1]
            else:
                frame = request_frame(self.node, request)
                if len(self._frames) >= FRAME_CACHE:
                    self._frames.clear()
                self._frames[id(request)] = (request, frame)
            self._out.append(frame)
        out, self._out = self._out, []
        return out

    def take_completed(self) -> list[SdoTicket]:
        done, self._done = self._done, []
        return done

    # -- responses ------------------------------------------------------------------------------------------------

    def _response(self, data: bytes, now: float) -> None:
        ticket = self._current
        if ticket is None:
            self.stale += 1  # the quiet period's purpose: a late reply to a transfer that ended
            return
        if len(data) != 8:
            self.malformed += 1
            return
        command, index, sub = _MUX.unpack_from(data)
        request = ticket.request
        if (index, sub) != (request.index, request.sub):
            self.stale += 1
            return
        specifier = command & 0xE0
        if specifier == _ABORT:
            code = int.from_bytes(data[4:8], "little")
            self._end(
                ticket, now, error=RemoteDeviceError("CANopen SDO", code, abort_meaning(code), self._what(request))
            )
        elif isinstance(request, Upload) and specifier == _UPLOAD_RESPONSE:
            if command & _EXPEDITED:
                size = 4 - (command >> 2 & 3) if command & _SIZE_GIVEN else 4
                self._end(ticket, now, result=bytes(data[4 : 4 + size]))
            else:
                self._out.append(abort_frame(self.node, index, sub, ABORT_COMMAND))
                offered = f" of {int.from_bytes(data[4:8], 'little')} bytes" if command & _SIZE_GIVEN else ""
                refused = SegmentedTransferError(
                    f"{self._what(request)}: the node offers a segmented upload{offered}; only expedited "
                    "transfers (up to 4 bytes) are supported"
                )
                self._end(ticket, now, error=refused)
        elif isinstance(request, Download) and specifier == _DOWNLOAD_RESPONSE:
            self._end(ticket, now, result=b"")
        else:
            self._forget(now)  # not the answer to this transfer: its own may still come
            frame = CanFrame(SDO_RESPONSE + self.node, bytes(data)).text()
            error = DecodeError(f"{self._what(request)}: unexpected SDO response {frame}", bytes(data), "SDO command")
            self._end(ticket, now, error=error)

    def _forget(self, now: float) -> None:
        """The transfer under way ends without its answer: nothing goes to the node for one timeout after the
        time its answer was due, and what the node answers meanwhile is dropped."""
        ticket = self._current
        assert ticket is not None
        self._quiet_until = max(now, self._answer_by) + ticket.request.timeout
        self._current = None
        self._answer_by = math.inf

    def _end(
        self, ticket: SdoTicket, now: float, result: bytes | None = None, error: StarterbusError | None = None
    ) -> None:
        if ticket is self._current:
            self._current = None
            self._answer_by = math.inf
        if error is not None:
            ticket.failed(error, now)
        else:
            assert result is not None
            ticket.done(result, now)
        self._done.append(ticket)
