"""An RTU line's :class:`~starterbus.transports.modbus.master.rtu_engine.RtuEngine` on the line's descriptor.

:class:`RtuDriver` is the loop body for a line (a :class:`~starterbus.core.media.StreamDriver`): the fleet's
:class:`~starterbus.transports.modbus.driver.line_task.LineTask` steps it itself. :class:`RtuJobDriver` is the
same driver on the process's scheduler: the blocking callers' transactions (:meth:`RtuLine.run
<starterbus.transports.modbus.driver.line.RtuLine.run>`) become its tickets while the scheduler's own thread runs
the loop (a service: ``poll``, ``serve``, ``opcua``), so that thread alone does the line's I/O. Both hold the line's
lock while a transaction is theirs, as the blocking driver does, and share the line's guard: the rules are written
once. The line is named here by what the drivers use of it (:class:`Line`), so this module needs no import of
``line.py``, which makes its :class:`RtuJobDriver`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from typing import Any, Protocol

from starterbus.core import (
    FOREVER,
    Scheduler,
    StarterbusError,
    StreamDriver,
    Ticket,
    TicketState,
    TransportError,
)
from starterbus.transports.modbus.driver.link import Link
from starterbus.transports.modbus.master.guard import LineGuard
from starterbus.transports.modbus.master.rtu_engine import ANSWER, QUIET, READ_CHUNK, START, TRAIL, RtuEngine

__all__ = ["CONNECT_LOOK", "LOCK_RETRY", "Line", "RtuDriver", "RtuJobDriver"]

_DONE, _FAILED = TicketState.DONE, TicketState.FAILED  # (an Enum class's attributes are slow to read)
_START, _QUIET, _ANSWER, _TRAIL = START, QUIET, ANSWER, TRAIL

#: how soon a driver or task looks again at a line that another user holds
LOCK_RETRY = 0.001
#: how soon a driver or task looks again at a TCP line's connection being made (the loop does not wait for it)
CONNECT_LOOK = 0.005


class Line(Protocol):
    """What the drivers use of an :class:`~starterbus.transports.modbus.driver.line.RtuLine`."""

    guard: LineGuard
    link: Link
    lock: threading.Lock
    transactions: int
    requests: int
    retries: int
    broken: bool  # a transport error broke the link (or it is closed): reopened before the next transaction

    @property
    def name(self) -> str: ...

    @property
    def clock(self) -> Callable[[], float]: ...

    def mark_broken(self) -> None: ...

    def broke(self, exc: StarterbusError) -> None: ...

    def usable_link(self) -> Link: ...

    def reopen(self) -> bool: ...


class RtuDriver(StreamDriver[RtuEngine]):
    """An :class:`RtuEngine` on a line's link (a serial port or pty, a TCP connection to a device server):
    reads exactly what the engine wants, with the line's clock read after each read and before each write."""

    def __init__(self, line: Line) -> None:
        super().__init__(line.name, lambda: RtuEngine(line.guard, line.name))
        self.line = line
        self._clock = line.clock
        #: the last reading of the line's clock in a step (the fleet's poll times its next look with it)
        self.at = 0.0

    @property
    def fd(self) -> int:
        return self.line.link.fd

    def usable(self, now: float) -> bool:
        return True

    def take_input(self, now: float) -> None:
        self.look()

    def look(self) -> float:
        """Read what is there (at most what the engine wants) and give it to the engine; the time after."""
        engine, line = self.engine, self.line
        if line.broken:  # closed after an answer: the rest of its silence is waited for by time alone
            at = self._clock()
            engine.receive(None, at)
            return at
        if engine.phase is _ANSWER:
            data = line.link.read_ready(engine.want)
        else:
            try:
                data = line.link.take_input(READ_CHUNK)
            except TransportError:
                if engine.phase is not _TRAIL:
                    raise
                line.mark_broken()  # the connection closed after the answer: no byte followed it
                data = b""
        at = self._clock()
        engine.receive(data or None, at)
        return at

    def step(self, now: float, ready: bool) -> None:
        """The loop body for a line: the input is looked at first, unless a request is due and the input was
        found empty a moment ago (the silence after the last answer), as the blocking driver does. The frames
        written and the retries begun are added to the line's counts (a step that raises is the crash's)."""
        engine, clock = self.engine, self._clock
        requests, retries = engine.requests, engine.retries
        phase = engine.phase
        if phase is _START or phase is _QUIET:
            now = clock()
            if phase is _QUIET or engine.guard.must_discard(now):
                now = self.look()
        else:
            # (an answer complete in this look is followed by the watch of its silence: bytes after it wake the
            # loop, the silence's end looks again)
            now = self.look()
            phase = engine.phase
        if phase is not _START and now >= engine.deadline:  # (START is due at once: take_output decides)
            engine.advance(now)
            phase = engine.phase
        if phase is _START or phase is _QUIET:
            # the clock was read no earlier than the request's first byte: by the look, or just above
            if engine.guard.must_discard(now):  # not looked at a moment ago (a retry after a timeout)
                now = self.look()
            out = engine.take_output(now)
            if out:
                self.line.link.write(out[0])
        self.at = now
        done = engine.take_completed()
        if done:  # (nothing ended: nothing to complete, and the tickets left are as they were)
            self.complete(now, done)
        if engine.requests != requests or engine.retries != retries:
            line = self.line
            line.requests += engine.requests - requests
            line.retries += engine.retries - retries

    def write(self, units: Sequence[Any], now: float) -> None:
        self.line.link.write(units[0])


class RtuJobDriver(RtuDriver):
    """The blocking callers' transactions on ``line`` as tickets of ``loop``, served by it only while it has some.

    A ticket waits until the line's lock is free (a fleet's poll holds it from a request's start to its answer's
    delivery; the poll leaves the line to the tickets waiting here before it takes it again), then the driver holds
    the lock until it has no ticket left: the engine's order, not the lock, keeps one transaction at a time among
    them. The loop watches the line's descriptor only meanwhile. What a ticket put on the wire goes to the line's
    counts here; a transport error breaks the line (reopened before the next ticket's request)."""

    def __init__(self, line: Line, loop: Scheduler) -> None:
        super().__init__(line)
        self.loop = loop
        self._served = False  # in the loop's drivers (only while tickets are out)
        self._locked = False
        self._retry_at = 0.0
        self._connecting = False  # the line's TCP connection is being made (looked at again at _retry_at)
        #: tickets are out (read by the fleet's poll, in the loop, before it takes the line: they go first)
        self.waiting = False

    @property
    def fd(self) -> int:
        line = self.line
        return line.link.fd if self._locked and not line.broken else -1

    @property
    def deadline(self) -> float:
        if self._locked and not self._connecting:
            return float(self.engine.deadline)
        return self._retry_at if self.engine.pending else FOREVER

    def submit(
        self, requests: Sequence[Any], now: float, futures: Sequence[Future[Any] | None]
    ) -> list[Ticket[Any, Any]]:
        tickets = super().submit(requests, now, futures)
        self.waiting = True
        if not self._served:
            self._served = True
            self.loop.add(self)
        return tickets

    def step(self, now: float, ready: bool) -> None:
        line, engine = self.line, self.engine
        if not self._locked:
            if not engine.pending:
                return
            if not line.lock.acquire(blocking=False):
                self._retry_at = line.clock() + LOCK_RETRY
                return
            self._locked = True
        phase = engine.phase
        if line.broken and (phase is _START or phase is _QUIET):  # (broken under an answer: its silence first)
            # (a TransportError: the loop crashes the driver, every ticket fails with it)
            self._connecting = not line.reopen()
            if self._connecting:
                self._retry_at = line.clock() + CONNECT_LOOK
                return
        RtuDriver.step(self, now, ready)

    def complete(self, now: float, done: Sequence[Ticket[Any, Any]] | None = None) -> None:
        if done is None:
            done = self.engine.take_completed()
        for ticket in done:
            self._ended(ticket)
        super().complete(now, done)
        if not self.engine.pending:
            self._idle()

    def crash(self, error: StarterbusError, now: float) -> None:
        """Every ticket fails with ``error`` (the line is broken by a transport error); the line is let go."""
        for ticket in list(self._futures):
            if not ticket.ended:
                ticket.failed(error, now)
            self._ended(ticket)
        super().crash(error, now)
        self._idle()

    def _ended(self, ticket: Ticket[Any, Any]) -> None:
        line, state = self.line, ticket.state
        if state is _DONE or state is _FAILED or ticket.attempts:
            line.transactions += 1
        if state is _FAILED:
            assert ticket.error is not None
            line.broke(ticket.error)

    def _idle(self) -> None:
        """No ticket left: the line's lock given back, the driver no longer served."""
        self.waiting = False
        self._connecting = False
        if self._locked:
            self._locked = False
            self.line.lock.release()
        if self._served:
            self._served = False
            self.loop.remove(self)
