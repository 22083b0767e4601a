"""The one surface of every protocol engine, and the ticket that says which request a result answers.

An engine is a pure object in the manner of h11's ``Connection``: it is given requests (:meth:`Engine.submit`),
received data and the time (:meth:`~Engine.receive`, :meth:`~Engine.advance`); it gives what to send
(:meth:`~Engine.take_output`), when it next needs the time (:attr:`~Engine.deadline`) and the tickets that
ended (:meth:`~Engine.take_completed`). It reads no clock, holds no lock and does no I/O, so a transcript of
its inputs replays to the same outputs and completions. A driver (:mod:`starterbus.core.media`) runs it on one
medium and the scheduler (:mod:`starterbus.core.scheduler`) runs every driver of the process.

The rules written once (docs/engine.md, checked for any engine by :mod:`starterbus.testing.engines`):

1. One caller at a time: only the scheduler's leader calls an engine.
2. A result goes to the ticket it answers, once: a :class:`Ticket` refuses a second end
   (:class:`TicketStateError`).
3. Late replies are never values: a ticket that timed out or was cancelled after it was sent is forgotten; a
   reply to it is counted as stale and completes nothing.
4. Cancelled before it was sent, a ticket is dropped with nothing on the wire; after, it is a failed attempt.
5. ``deadline`` moves forward after ``advance(deadline)`` (no busy loop).
6. Timeouts belong to the engine; a waiter has only an outer bound that catches a stalled scheduler.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

from starterbus.core.errors import StarterbusError

__all__ = ["FOREVER", "Engine", "StreamEngine", "Ticket", "TicketState", "TicketStateError"]

Req = TypeVar("Req")
Res = TypeVar("Res")
Unit = TypeVar("Unit")

#: a deadline that never comes: only input or a submission matter
FOREVER = math.inf


class TicketStateError(StarterbusError):
    """A ticket was moved against its life cycle (a second completion, a send after its end): an engine's bug,
    refused before a result could reach the wrong request."""


class TicketState(enum.Enum):
    QUEUED = "queued"
    SENT = "sent"
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"


# module constants, compared by identity (an Enum class's attribute goes through the enum type's __getattr__ hook)
_QUEUED, _SENT, _DONE = TicketState.QUEUED, TicketState.SENT, TicketState.DONE
_FAILED, _CANCELLED = TicketState.FAILED, TicketState.CANCELLED


@dataclass(eq=False, slots=True)
class Ticket(Generic[Req, Res]):
    """One request and its fate: QUEUED -> SENT -> DONE | FAILED | CANCELLED, each transition once (a QUEUED
    ticket may also end at once: failed or cancelled before it was sent). ``attempts`` counts the sends (an
    engine that repeats a request sends the same ticket again); ``sent_at``: the first send; ``done_at``: the
    end. Compared by identity: a ticket is one request, whatever it holds."""

    request: Req
    state: TicketState = TicketState.QUEUED
    result: Res | None = None
    error: StarterbusError | None = None
    attempts: int = 0
    sent_at: float | None = None
    done_at: float | None = None

    @property
    def ended(self) -> bool:
        state = self.state  # by identity: hashing an enum member is a Python-level call (hot in every wait)
        return state is not _QUEUED and state is not _SENT

    def sent(self, now: float) -> None:
        """One more send of the request (the first moves it to SENT)."""
        if self.ended:
            raise TicketStateError(f"ticket for {self.request!r} sent after it ended ({self.state.value})")
        if self.state is _QUEUED:
            self.state = _SENT
            self.sent_at = now
        self.attempts += 1

    def done(self, result: Res, now: float) -> None:
        self._end(_DONE, now)
        self.result = result

    def failed(self, error: StarterbusError, now: float) -> None:
        self._end(_FAILED, now)
        self.error = error

    def cancelled(self, now: float) -> None:
        self._end(_CANCELLED, now)

    def _end(self, state: TicketState, now: float) -> None:
        if self.ended:
            raise TicketStateError(
                f"ticket for {self.request!r} ended twice: {self.state.value}, then {state.value} (a result "
                "goes to the ticket it answers, once)"
            )
        self.state = state
        self.done_at = now

    def outcome(self) -> Res:
        """The result of a DONE ticket; a FAILED one raises its error; a CANCELLED one a TicketStateError."""
        if self.state is _DONE:
            return self.result  # type: ignore[return-value]  # set with DONE
        if self.error is not None:
            raise self.error
        raise TicketStateError(f"ticket for {self.request!r} has no result: {self.state.value}")


class Engine(Protocol[Req, Res, Unit]):
    """A sans-IO protocol machine. ``Unit``: what the medium carries (bytes of a stream, a CAN frame...)."""

    @property
    def deadline(self) -> float:
        """When :meth:`advance` is next due (monotonic seconds); :data:`FOREVER`: only input or submit matter."""
        ...

    def submit(self, request: Req, now: float) -> Ticket[Req, Res]:
        """Queue the request; its ticket ends exactly once (``take_completed``)."""
        ...

    def cancel(self, ticket: Ticket[Req, Res], now: float) -> None:
        """Drop the ticket: unsent, nothing goes out; sent, a failed attempt whose late reply is stale."""
        ...

    def receive(self, data: Unit | None, now: float) -> None:
        """What the medium gave at ``now``; None: it was looked at and nothing was there."""
        ...

    def advance(self, now: float) -> None:
        """The time is ``now`` (timeouts, silences)."""
        ...

    def take_output(self, now: float) -> Sequence[Unit]:
        """What to write at once; ``now``: the clock read just before the write."""
        ...

    def take_completed(self) -> Sequence[Ticket[Req, Res]]:
        """The tickets that ended since the last call, in the order they ended."""
        ...


class StreamEngine(Engine[Req, Res, bytes], Protocol[Req, Res]):
    """An engine on a connection that can break and be made again (a TCP socket): the driver tells it."""

    @property
    def broken(self) -> str | None:
        """Why the stream is out of step (the driver then drops the connection); None while it is usable."""
        ...

    def lost(self, error: StarterbusError, now: float) -> None:
        """The connection is gone: every sent ticket fails with ``error``; queued ones wait for the next."""
        ...

    def refuse(self, error: StarterbusError, now: float) -> None:
        """No connection can be had now: every queued ticket fails with ``error``."""
        ...

    @property
    def pending(self) -> int:
        """Tickets not yet ended (the driver connects while there are some)."""
        ...
