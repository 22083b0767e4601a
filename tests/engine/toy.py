"""A toy request/reply engine over a byte stream, for the engine core's tests: a frame is ``length | id |
payload``; the peer answers a request with its payload upper-cased under the same id. Ids tell answers apart;
one transaction at a time (``outstanding``), ``attempts`` sends each, a late or unknown id is stale."""

from __future__ import annotations

from collections import deque

from starterbus.core.engine import FOREVER, Ticket
from starterbus.core.errors import DecodeError, StarterbusError, TimeoutError

ToyTicket = Ticket[bytes, bytes]


def frame(ident: int, payload: bytes) -> bytes:
    return bytes((len(payload) + 1, ident)) + payload


class ToyEngine:
    def __init__(self, timeout: float = 0.1, attempts: int = 2, outstanding: int = 1) -> None:
        self.timeout, self.attempts, self.outstanding = timeout, attempts, outstanding
        self._queue: deque[ToyTicket] = deque()
        self._sent: dict[int, tuple[ToyTicket, float]] = {}  # id -> ticket, its answer's deadline
        self._done: list[ToyTicket] = []
        self._next = 0
        self._buffer = bytearray()
        self.stale = 0
        self.broken: str | None = None

    @property
    def deadline(self) -> float:
        return min((at for _, at in self._sent.values()), default=FOREVER)

    @property
    def pending(self) -> int:
        return len(self._queue) + len(self._sent)

    def submit(self, request: bytes, now: float) -> ToyTicket:
        ticket: ToyTicket = Ticket(request)
        self._queue.append(ticket)
        return ticket

    def cancel(self, ticket: ToyTicket, now: float) -> None:
        if ticket in self._queue:
            self._queue.remove(ticket)
        for ident, (sent, _) in list(self._sent.items()):
            if sent is ticket:
                del self._sent[ident]
        ticket.cancelled(now)
        self._done.append(ticket)

    def receive(self, data: bytes | None, now: float) -> None:
        if not data:
            return
        self._buffer += data
        while self._buffer and len(self._buffer) > self._buffer[0]:
            length = self._buffer[0]
            if length == 0:
                self.broken = "a frame of length 0: the stream is out of step"
                self._buffer.clear()
                return
            ident, payload = self._buffer[1], bytes(self._buffer[2 : length + 1])
            del self._buffer[: length + 1]
            entry = self._sent.pop(ident, None)
            if entry is None:
                self.stale += 1
                continue
            ticket = entry[0]
            if payload != ticket.request.upper():
                self._failed(ticket, DecodeError("not the answer", payload, "payload"), now)
            else:
                ticket.done(payload, now)
                self._done.append(ticket)

    def advance(self, now: float) -> None:
        for ident, (ticket, at) in list(self._sent.items()):
            if at <= now:
                del self._sent[ident]
                self._failed(ticket, TimeoutError(f"no answer to {ticket.request!r}"), now)

    def take_output(self, now: float) -> list[bytes]:
        out = []
        while self._queue and len(self._sent) < self.outstanding:
            ticket = self._queue.popleft()
            ident, self._next = self._next, (self._next + 1) % 256
            ticket.sent(now)
            self._sent[ident] = (ticket, now + self.timeout)
            out.append(frame(ident, ticket.request))
        return out

    def take_completed(self) -> list[ToyTicket]:
        done, self._done = self._done, []
        return done

    def lost(self, error: StarterbusError, now: float) -> None:
        for ticket, _ in self._sent.values():
            ticket.failed(error, now)
            self._done.append(ticket)
        self._sent.clear()
        self._buffer.clear()
        self.broken = None

    def refuse(self, error: StarterbusError, now: float) -> None:
        while self._queue:
            ticket = self._queue.popleft()
            ticket.failed(error, now)
            self._done.append(ticket)

    def _failed(self, ticket: ToyTicket, error: StarterbusError, now: float) -> None:
        if ticket.attempts < self.attempts:
            self._queue.appendleft(ticket)  # sent again, with a new id
        else:
            ticket.failed(error, now)
            self._done.append(ticket)


class ToyPeer:
    """Answers every whole frame at once, each frame its own reply."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def replies(self, unit: bytes) -> list[bytes]:
        self._buffer += unit
        out = []
        while self._buffer and len(self._buffer) > self._buffer[0]:
            length = self._buffer[0]
            out.append(frame(self._buffer[1], bytes(self._buffer[2 : length + 1]).upper()))
            del self._buffer[: length + 1]
        return out

    def answers(self, request: bytes, result: bytes) -> bool:
        return result == request.upper()


def request(n: int) -> bytes:
    return f"r{n}".encode()
