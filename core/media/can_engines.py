"""The engines on one CAN bus (:class:`~starterbus.core.media.can.CanDriver`'s half that is not the bus): what an
engine is (:class:`CanEngine`, :class:`ToEngine`), and :class:`EngineSet`: each received frame routed to the
engines that want its identifier, what they give written (and looped back to the other engines that want it),
their tickets' futures ended."""

from __future__ import annotations

import collections
import logging
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future, InvalidStateError
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import can

from starterbus.core.canframe import CanFrame
from starterbus.core.engine import Engine, Ticket, TicketState
from starterbus.core.errors import StarterbusError, TransportError
from starterbus.core.media.can_reader import CanReader

__all__ = ["CanEngine", "EngineSet", "Handoff", "Loop", "ToEngine"]

log = logging.getLogger("starterbus.core.media.can")  # the driver's logger: its engines' failures are its

T = TypeVar("T")


class Loop(Protocol):
    """What the driver needs of the scheduler (:class:`starterbus.core.Scheduler`; named here, not imported: the
    scheduler's module imports the media's)."""

    clock: Callable[[], float]

    @property
    def running(self) -> bool: ...
    def call(self, fn: Callable[[float], T]) -> Future[T]: ...
    def wait(self, future: Future[T], bound: float, what: str) -> T: ...
    def submit(self, driver: Any, request: object) -> Future[Any]: ...
    def add(self, driver: Any) -> None: ...
    def remove(self, driver: Any) -> None: ...
    def start(self) -> object: ...
    def stop(self) -> object: ...


class CanEngine(Engine[Any, Any, CanFrame], Protocol):
    """An engine on a CAN bus: the identifiers it wants routed to it (may change: read at each step)."""

    @property
    def wanted(self) -> frozenset[int]: ...


@dataclass(frozen=True, slots=True)
class ToEngine:
    """A request for one engine of a :class:`CanDriver` (what ``Scheduler.run`` / ``submit`` are given)."""

    engine: CanEngine
    request: object


class Handoff:
    """A ticket submitted in its caller's own thread (``CanDriver.submit_here``) and ended in the loop: one lock,
    released by the loop when the ticket ends (what a ``Future`` costs twice over: a condition, a reentrant lock,
    a lock per wait). :meth:`wait` for it where the loop's own thread ends it; :meth:`follow` gives a future to
    wait on through the scheduler (which the caller leads when no thread does)."""

    __slots__ = ("_ended", "future", "ticket")

    def __init__(self, ticket: Ticket[Any, Any]) -> None:
        self.ticket = ticket
        self._ended = threading.Lock()
        self._ended.acquire()
        self.future: Future[Ticket[Any, Any]] | None = None

    def set_result(self, ticket: Ticket[Any, Any]) -> None:
        """The ticket ended (the loop's: ``EngineSet._end``)."""
        self._ended.release()
        future = self.future  # read after the release: a future made before it is set here, one made after sees it
        if future is not None:
            _settle(future, ticket)

    @property
    def ended(self) -> bool:
        return self.wait(0.0)

    def wait(self, timeout: float) -> bool:
        """Up to ``timeout`` s for the ticket's end; whether it ended."""
        ended = self._ended
        if ended.acquire(timeout=timeout) if timeout > 0 else ended.acquire(blocking=False):
            ended.release()
            return True
        return False

    def follow(self) -> Future[Ticket[Any, Any]]:
        """A future that gets the ticket when it ends (now, if it has)."""
        future: Future[Ticket[Any, Any]] = Future()
        self.future = future
        if self.ended:  # (perhaps before the future was there)
            _settle(future, self.ticket)
        return future


def _settle(future: Future[Ticket[Any, Any]], ticket: Ticket[Any, Any]) -> None:
    try:
        future.set_result(ticket)
    except InvalidStateError:  # set by the other side of a Handoff meanwhile
        pass


class EngineSet:
    """The engines of a :class:`~starterbus.core.media.can.CanDriver` and their tickets (its attributes, set by
    its ``__init__``; in the loop only)."""

    name: str
    engines: list[CanEngine]
    errors: collections.deque[str]
    crashes: int
    _seen: list[frozenset[int]]
    _routes: dict[int, tuple[CanEngine, ...]]
    _futures: dict[Ticket[Any, Any], Future[Any] | Handoff | None]
    _owner: dict[Ticket[Any, Any], CanEngine]
    _batches: dict[Ticket[Any, Any], list[Ticket[Any, Any]]]
    _reader: CanReader | None
    _dropped: int

    def write(self, frames: Sequence[CanFrame]) -> None:
        raise NotImplementedError  # the bus's (CanDriver.write)

    # -- frames to the engines ------------------------------------------------------------------------------------

    def _deliver(self, messages: list[can.Message], now: float) -> set[CanEngine]:
        """Give each frame read to the engines that want it; then what they answer goes out. Returns those
        engines."""
        self._sync_routes()
        routes = self._routes
        touched: set[CanEngine] = set()
        for message in messages:
            engines = routes.get(message.arbitration_id)
            if engines is None or message.is_extended_id or message.is_remote_frame or message.is_error_frame:
                self._dropped += 1
                continue
            if message.is_fd or message.dlc > 8:
                self._dropped += 1
                continue
            frame = CanFrame(message.arbitration_id, bytes(message.data))
            for engine in engines:
                try:
                    engine.receive(frame, now)
                except Exception as exc:
                    self._failed(engine, exc, now, f"frame {frame.text()}")
                touched.add(engine)
        for engine in touched:  # answers go out after the burst, each engine's in order
            self._flush(engine, now)
        return touched

    def _sync_routes(self) -> None:
        """Route again if an engine's ``wanted`` changed (compared by identity: an engine gives a new set)."""
        engines, seen = self.engines, self._seen
        if len(seen) == len(engines):
            for engine, wanted in zip(engines, seen, strict=True):
                if engine.wanted is not wanted:
                    break
            else:
                return
        self._route()

    def _route(self) -> None:
        routes: dict[int, list[CanEngine]] = {}
        for engine in self.engines:
            for can_id in engine.wanted:
                routes.setdefault(can_id, []).append(engine)
        self._routes = {can_id: tuple(engines) for can_id, engines in routes.items()}
        self._seen = [engine.wanted for engine in self.engines]
        if self._reader is not None:
            self._reader.wanted = frozenset(self._routes)

    def _flush(self, engine: CanEngine, now: float) -> None:
        """Write what the engine has to send; end the futures of its tickets that ended. The routes follow its
        ``wanted`` first: the reader must queue the answer to what goes out now."""
        self._sync_routes()
        try:
            out = engine.take_output(now)
        except Exception as exc:
            self._failed(engine, exc, now, "output")
            out = ()
        if out:
            self.write(out)
            if len(self.engines) > 1:
                self._loop_back(engine, out, now)
        self._complete(engine, now)

    def _loop_back(self, sender: CanEngine | None, frames: Sequence[CanFrame], now: float) -> None:
        """What one engine wrote reaches the others on the bus that want it, as it reaches separate sockets on
        one interface (python-can delivers no frame back to the bus that sent it)."""
        touched: list[CanEngine] = []
        for frame in frames:
            for engine in self._routes.get(frame.can_id, ()):
                if engine is not sender:
                    try:
                        engine.receive(frame, now)
                    except Exception as exc:
                        self._failed(engine, exc, now, f"frame {frame.text()}")
                    if engine not in touched:
                        touched.append(engine)
        for engine in touched:
            self._flush(engine, now)

    def _failed(self, engine: CanEngine, exc: Exception, now: float, where: str) -> None:
        if isinstance(exc, StarterbusError):  # a malformed frame: never stops the bus
            self.errors.append(str(exc))
            return
        log.exception("%s: engine %s failed (%s)", self.name, type(engine).__name__, where)
        self.errors.append(f"{type(exc).__name__}: {exc}")

    # -- tickets --------------------------------------------------------------------------------------------------

    def _complete(self, engine: CanEngine, now: float) -> None:
        done = engine.take_completed()
        while done:
            withdrawn = False
            for ticket in done:
                batch = self._batches.pop(ticket, None)
                if batch is not None and ticket.state is not TicketState.DONE:
                    for other in batch:
                        if not other.ended:
                            engine.cancel(other, now)
                            withdrawn = True
                self._end(ticket)
            done = engine.take_completed() if withdrawn else []

    def _end(self, ticket: Ticket[Any, Any]) -> None:
        future = self._futures.pop(ticket, None)
        self._owner.pop(ticket, None)
        self._batches.pop(ticket, None)
        if future is not None:
            future.set_result(ticket)

    # -- what the scheduler calls ---------------------------------------------------------------------------------

    def submit(
        self, requests: Sequence[Any], now: float, futures: Sequence[Future[Any] | None]
    ) -> list[Ticket[Any, Any]]:
        """Queue each :class:`ToEngine` on its engine (one batch: the first to fail withdraws the others)."""
        tickets: list[Ticket[Any, Any]] = []
        for routed, future in zip(requests, futures, strict=True):
            if not isinstance(routed, ToEngine) or routed.engine not in self.engines:
                raise TransportError(f"{self.name}: {routed!r} is not a request for an engine on this bus")
            ticket = routed.engine.submit(routed.request, now)
            self._futures[ticket] = future
            self._owner[ticket] = routed.engine
            tickets.append(ticket)
        if len(tickets) > 1:
            for ticket in tickets:
                self._batches[ticket] = tickets
        for engine in {self._owner[t] for t in tickets}:
            self._flush(engine, now)
        return tickets

    def withdraw(self, tickets: Sequence[Ticket[Any, Any]], now: float) -> None:
        for ticket in tickets:
            engine = self._owner.get(ticket)
            if engine is not None and not ticket.ended:
                engine.cancel(ticket, now)
                self._complete(engine, now)

    def cancel(self, futures: Sequence[Future[Any]], now: float) -> None:
        withdrawn = set(futures)
        self.withdraw([t for t, f in list(self._futures.items()) if f in withdrawn], now)

    def crash(self, error: StarterbusError, now: float) -> None:
        """A step raised past the engines' own containment (the bus): every ticket fails; the engines stay."""
        self.crashes += 1
        self.errors.append(str(error))
        self._fail_all(error, now)

    def _fail_all(self, error: StarterbusError, now: float) -> None:
        for ticket in list(self._futures):
            if not ticket.ended:
                ticket.failed(error, now)
            self._end(ticket)
