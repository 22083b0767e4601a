"""The one driver loop body, and the driver of a byte stream with a file descriptor.

A driver owns one medium and the engine on it; the scheduler steps it when its descriptor is ready or its
deadline has come. The body (:meth:`Driver.step`), written once for every medium:

1. read what is ready and ``receive`` it (reading before writing: input found just before a send is the
   engine's to judge, never mistaken for the answer to it);
2. ``advance(now)`` when the engine's deadline has come;
3. ``take_output(now)`` and write it;
4. end the futures of the tickets of ``take_completed()``;
5. the scheduler then reads the driver's descriptor and deadline.

A ticket's future gets the ended ticket (DONE, FAILED or CANCELLED): the waiter reads its result or error.
"""

from __future__ import annotations

import socket
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from typing import Any, Generic, Protocol, TypeVar

from starterbus.core.engine import Engine, Ticket, TicketState
from starterbus.core.errors import StarterbusError, TransportError

__all__ = ["Driver", "Stream", "StreamDriver", "step_error"]

Req = TypeVar("Req")
Res = TypeVar("Res")
Unit = TypeVar("Unit")
E = TypeVar("E", bound=Engine[Any, Any, Any])

_DONE = TicketState.DONE  # (an Enum class's attributes are slow to read)

#: bytes taken from a stream per read (a Modbus ADU is at most 260)
READ_SIZE = 4096


def step_error(name: str, exc: Exception) -> StarterbusError:
    """What the tickets of driver ``name`` fail with when its step raised ``exc`` (the scheduler's rule, and a
    driver's own step made in the loop): a starterbus error as it is, anything else a TransportError naming the
    driver and the defect."""
    if isinstance(exc, StarterbusError):
        return exc
    return TransportError(f"{name}: {type(exc).__name__}: {exc}")


class Driver(Generic[E]):
    """An engine on a medium. Subclasses say how the medium is read and written; the scheduler steps it.

    ``make_engine`` makes the engine, and a fresh one after a crash (an engine that raised is not trusted with
    its old state: every ticket it held fails)."""

    def __init__(self, name: str, make_engine: Callable[[], E]) -> None:
        self.name = name
        self._make_engine = make_engine
        self.engine: E = make_engine()
        self._futures: dict[Ticket[Any, Any], Future[Any] | None] = {}  # None: its waiter leads, no future
        self._batches: dict[Ticket[Any, Any], list[Ticket[Any, Any]]] = {}
        self.crashes = 0

    # -- what the scheduler reads ---------------------------------------------------------------------------

    @property
    def fd(self) -> int:
        return -1

    @property
    def writing(self) -> bool:
        return False

    @property
    def deadline(self) -> float:
        return float(self.engine.deadline)

    @property
    def pending(self) -> int:
        """Tickets handed out and not ended."""
        return len(self._futures)

    # -- the loop body ----------------------------------------------------------------------------------------

    def step(self, now: float, ready: bool) -> None:
        if ready:
            self.take_input(now)
        if self.usable(now):
            engine = self.engine
            if now >= engine.deadline:
                engine.advance(now)
            self.complete(now)  # a batch that failed is withdrawn before its next request could go out
            out = engine.take_output(now)
            if out:
                self.write(out, now)
        self.complete(now)

    def take_input(self, now: float) -> None:
        """Read what is ready and give it to the engine (the medium's own)."""

    def usable(self, now: float) -> bool:
        """Whether the medium can be written now (a stream may be connecting, or down)."""
        return True

    def write(self, units: Sequence[Any], now: float) -> None:
        """Put ``units`` on the medium."""
        raise NotImplementedError

    def complete(self, now: float, done: Sequence[Ticket[Any, Any]] | None = None) -> None:
        """End the futures of the ended tickets (``done``: what the engine's ``take_completed`` just gave, if the
        caller took it); a ticket of a batch that ended so (:meth:`ends_batch`: other than DONE) withdraws the batch's
        tickets that have not ended (cancelled: never sent, or forgotten)."""
        if done is None:
            done = self.engine.take_completed()
        while done:
            withdrawn = False
            for ticket in done:
                future = self._futures.pop(ticket, None)
                batch = self._batches.pop(ticket, None)
                if batch is not None and self.ends_batch(ticket):
                    for other in batch:
                        if not other.ended:
                            self.engine.cancel(other, now)
                            withdrawn = True
                if future is not None:
                    future.set_result(ticket)
            done = self.engine.take_completed() if withdrawn else []

    def ends_batch(self, ticket: Ticket[Any, Any]) -> bool:
        """Whether ``ticket``'s end withdraws the rest of its batch: an end other than DONE (a medium's driver may
        add its own, as a refusal)."""
        return ticket.state is not _DONE

    # -- what the scheduler calls -------------------------------------------------------------------------------

    def submit(
        self, requests: Sequence[Any], now: float, futures: Sequence[Future[Any] | None]
    ) -> list[Ticket[Any, Any]]:
        """Queue the requests as one batch (the first to fail withdraws the others); each future (None: its
        waiter leads and watches the ticket) gets its ticket once it ends."""
        engine = self.engine
        if len(requests) == 1:  # the usual case (a sync call): no batch
            (future,) = futures
            ticket = engine.submit(requests[0], now)
            self._futures[ticket] = future
            return [ticket]
        tickets: list[Ticket[Any, Any]] = [engine.submit(request, now) for request in requests]
        for ticket, future in zip(tickets, futures, strict=True):
            self._futures[ticket] = future
        if len(tickets) > 1:
            for ticket in tickets:
                self._batches[ticket] = tickets
        return tickets

    def withdraw(self, tickets: Sequence[Ticket[Any, Any]], now: float) -> None:
        """Cancel those of the tickets that have not ended (in the loop)."""
        for ticket in tickets:
            if not ticket.ended:
                self.engine.cancel(ticket, now)
        self.complete(now)

    def cancel(self, futures: Sequence[Future[Any]], now: float) -> None:
        """Cancel the tickets of these futures that have not ended (in the loop: through
        :meth:`Scheduler.call`); their futures get the cancelled tickets."""
        withdrawn = set(futures)
        for ticket, future in list(self._futures.items()):
            if future in withdrawn and not ticket.ended:
                self.engine.cancel(ticket, now)
        self.complete(now)

    def crash(self, error: StarterbusError, now: float) -> None:
        """A step raised: every ticket handed out fails with ``error``; the next ones go to a fresh engine."""
        self.crashes += 1
        futures, self._futures = self._futures, {}
        self._batches.clear()
        for ticket, future in futures.items():
            if not ticket.ended:
                ticket.failed(error, now)
            if future is not None:
                future.set_result(ticket)
        self.drop_medium()
        self.engine = self._make_engine()

    def drop_medium(self) -> None:
        """Let go of the medium after a crash (made again on demand where the driver can)."""


class Stream(Protocol):
    """A connected byte stream with a descriptor (a socket; a pty or serial port through a small adapter)."""

    def fileno(self) -> int: ...
    def recv(self, size: int, /) -> bytes: ...
    def sendall(self, data: bytes, /) -> None: ...
    def close(self) -> None: ...


class StreamDriver(Driver[E]):
    """An engine on a byte stream: the descriptor watched for input, answers written at once. A stream that
    ends or fails is lost: :meth:`lost` (every ticket fails with a TransportError naming why, unless the
    subclass can make the stream again)."""

    def __init__(self, name: str, make_engine: Callable[[], E], stream: Stream | None = None) -> None:
        super().__init__(name, make_engine)
        self.stream = stream

    @property
    def fd(self) -> int:
        return self.stream.fileno() if self.stream is not None else -1

    def usable(self, now: float) -> bool:
        if self.stream is None:
            self.refuse(TransportError(f"{self.name}: not connected"), now)
            return False
        return True

    def take_input(self, now: float) -> None:
        stream = self.stream
        if stream is None:
            return
        try:
            data = stream.recv(READ_SIZE)
        except (BlockingIOError, InterruptedError):
            self.engine.receive(None, now)
            return
        except OSError as exc:
            self.lost(f"read failed: {exc}", now)
            return
        if not data:
            self.lost("the peer closed the connection", now)
            return
        self.engine.receive(data, now)

    def write(self, units: Sequence[Any], now: float) -> None:
        assert self.stream is not None
        data = units[0] if len(units) == 1 else b"".join(units)
        try:
            self.stream.sendall(data)
        except OSError as exc:
            self.lost(f"write failed: {exc}", now)

    def lost(self, why: str, now: float) -> None:
        """The stream is gone: close it; every ticket handed out fails (a reconnecting subclass keeps the
        queued ones for the next connection)."""
        self.close_stream()
        self.crash(TransportError(f"{self.name}: {why}"), now)

    def refuse(self, error: StarterbusError, now: float) -> None:
        """No stream now: every ticket fails with ``error``."""
        self.crash(error, now)
        self.crashes -= 1  # not a defect

    def close_stream(self) -> None:
        stream, self.stream = self.stream, None
        if stream is not None:
            if isinstance(stream, socket.socket):
                try:
                    stream.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
            stream.close()

    def drop_medium(self) -> None:
        self.close_stream()
