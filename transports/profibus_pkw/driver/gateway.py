"""A Profibus master gateway reached over Modbus TCP, on the one I/O engine (docs/engine.md, step 6).

One connection per gateway ``HOST:PORT`` (:class:`GatewayConnection`: an :class:`MbapEngine` on a
:class:`GatewayDriver`, a :class:`TcpDriver` of the process's scheduler; no thread, no pymodbus client), shared by
every station mapped on the gateway. One DP exchange of a station is a batch of Modbus transactions: an FC16 per
run of output words to write (a ``None`` word is left alone: passive PZD), then the FC03 or FC04 read of its input
words. The engine sends one transaction at a time, in the order they were queued, so the stations take turns and
a station's read always follows its own writes; the first transaction that fails withdraws the rest of its batch.

A station's cycle runs as a :class:`StationDriver` on the same scheduler: it writes its exchange ``(n, words)`` to
the connection and gets back ``(n, input words)`` or the error that ended it, at the next turn of the loop. The
numbers keep the rule of :class:`StationEngine`: only the exchange outstanding is an observation. The MBAP
transaction ids keep the same rule one level down: an answer to a transaction that timed out, was withdrawn or
belongs to no one is stale and dropped (:class:`MbapEngine`), never taken for the inputs of a later exchange.

Errors name the gateway: the connection's (cannot connect, closed, no answer within the timeout: a
:class:`TransportError` or :class:`TimeoutError`), the gateway's exception answers (a :class:`RemoteDeviceError`
of ``modbus-tcp`` with the standard text and what was asked), a wrong answer (a :class:`DecodeError`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from starterbus.core import (
    DecodeError,
    Driver,
    RemoteDeviceError,
    Scheduler,
    StarterbusError,
    TcpDriver,
    Ticket,
    TicketState,
    TransportError,
    process_scheduler,
)
from starterbus.spaces.modbus import STANDARD_EXCEPTION_TEXTS
from starterbus.transports.modbus.codec.frames import (
    ExceptionResponse,
    ReadInputRequest,
    ReadRequest,
    ReadResponse,
    Request,
    Response,
    WriteRegistersRequest,
)
from starterbus.transports.modbus.master.exchange import Exchange, TransactionPolicy
from starterbus.transports.modbus.master.mbap import MbapEngine
from starterbus.transports.profibus_pkw.master.station import DpOut, StationEngine

__all__ = ["STALL", "GatewayConnection", "GatewayDriver", "GatewayStation", "StationDriver"]

#: the outer bound of a blocking wait beyond the transactions' own timeouts: only a stalled loop gets there
STALL = 30.0


def describe(request: Request) -> str:
    """What a transaction asks, in messages."""
    if isinstance(request, WriteRegistersRequest):
        return f"FC16 write {len(request.values)} registers at {request.address}"
    assert isinstance(request, ReadRequest)
    return f"FC{request.function:02d} read {request.count} registers at {request.address}"


@dataclass(slots=True)
class _Pending:
    """One DP exchange of a station on the wire: its transactions' tickets."""

    station: StationDriver
    unit: DpOut
    tickets: list[Ticket[Exchange, Response]]


class GatewayDriver(TcpDriver[MbapEngine]):
    """The gateway's connection on a scheduler; it carries the stations' exchanges (:meth:`exchange`) and tells
    each station how its exchange ended."""

    def __init__(self, host: str, port: int, timeout: float, loop: Scheduler) -> None:
        name = f"gateway {host}:{port}"
        super().__init__(host, port, lambda: MbapEngine(outstanding=1, name=name), timeout)
        self.name = name
        self.loop = loop
        self.added = False
        self._pending: list[_Pending] = []

    def exchange(self, station: StationDriver, unit: DpOut, now: float) -> None:
        """Queue the transactions of one DP exchange of ``station`` and send what can go (in the loop)."""
        exchanges = station.gateway.transactions(unit[1])
        if not self.added and not self.closed:  # (closed: every transaction is refused at once, naming why)
            self.added = True
            self.loop.add(self)
        tickets = self.submit(exchanges, now, [None] * len(exchanges))
        self._pending.append(_Pending(station, unit, tickets))
        try:  # as the scheduler steps a driver: a defect here is the connection's, not the station's
            self.step(now, False)
        except Exception as exc:
            self.crash(exc if isinstance(exc, StarterbusError) else TransportError(f"{self.name}: {exc!r}"), now)

    def complete(self, now: float, done: Sequence[Ticket[Any, Any]] | None = None) -> None:
        """As :meth:`Driver.complete`, and a transaction the gateway refused (an exception answer: DONE for the
        Modbus engine) withdraws the rest of its batch too: no read goes out for an exchange whose write was
        refused. Then each exchange that ended goes back to its station."""
        engine = self.engine
        if done is None:
            done = engine.take_completed()
        ended = bool(done)
        while done:
            withdrawn = False
            for ticket in done:
                future = self._futures.pop(ticket, None)
                batch = self._batches.pop(ticket, None)
                refused = ticket.state is not TicketState.DONE or isinstance(ticket.result, ExceptionResponse)
                if batch is not None and refused:
                    for other in batch:
                        if not other.ended:
                            engine.cancel(other, now)
                            withdrawn = True
                if future is not None:
                    future.set_result(ticket)
            done = engine.take_completed() if withdrawn else []
        if ended and self._pending:
            self._tell(now)

    def crash(self, error: StarterbusError, now: float) -> None:
        super().crash(error, now)
        self._tell(now)

    def _tell(self, now: float) -> None:
        """Each exchange whose transactions have all ended goes back to its station."""
        left: list[_Pending] = []
        for pending in self._pending:
            tickets = pending.tickets
            for ticket in tickets:
                if not ticket.ended:
                    left.append(pending)
                    break
            else:
                try:
                    words: tuple[int, ...] | StarterbusError = pending.station.gateway.inputs(tickets)
                except StarterbusError as exc:
                    words = exc
                pending.station.answer(pending.unit, words)
        self._pending = left


class GatewayConnection:
    """One gateway's connection, shared by its stations (:data:`GATEWAYS` in ``channels.py``); the pool closes it
    when its last station lets go. Connected on demand (the first exchange), made again after a loss."""

    def __init__(self, host: str, port: int, timeout: float, loop: Scheduler | None = None) -> None:
        self.host, self.port, self.timeout = host, port, timeout
        self.loop = loop or process_scheduler()
        self.driver = GatewayDriver(host, port, timeout, self.loop)

    def run(self, exchanges: Sequence[Exchange], what: str) -> list[Ticket[Exchange, Response]]:
        """The transactions, waited for (a blocking call: outside the loop). The tickets, up to the first that
        did not end DONE."""
        loop, driver = self.loop, self.driver
        if not driver.added:

            def add(now: float) -> None:
                if not driver.added and not driver.closed:
                    driver.added = True
                    loop.add(driver)

            loop.wait(loop.call(add), STALL, f"{driver.name}: {what}")
        bound = STALL + self.timeout * (len(exchanges) + 1)
        return loop.run(driver, exchanges, bound, f"{driver.name}: {what}")

    def close(self) -> None:
        driver, loop = self.driver, self.loop

        def close(now: float) -> None:
            if driver.added:
                driver.added = False
                loop.remove(driver)
            driver.close(now)

        loop.wait(loop.call(close), STALL, f"{driver.name}: close")


class GatewayStation:
    """One station's register map on a gateway: the transactions of an exchange and the inputs of their answers.
    ``words``: the PPO's words per direction."""

    def __init__(
        self,
        connection: GatewayConnection,
        words: int,
        *,
        out: int,
        inp: int,
        unit: int,
        input_function: int,
    ) -> None:
        self.connection, self.words = connection, words
        self.out, self.inp, self.unit = out, inp, unit
        # one attempt each (the PKW engine repeats its task; a status read takes the next exchange); retry_writes
        # only keeps the Modbus engine's messages from pointing a failed write at a URL parameter PKW has not
        self.policy = TransactionPolicy(timeout=connection.timeout, retries=0, retry_writes=True)
        read = ReadInputRequest if input_function == 4 else ReadRequest
        self.read = Exchange(read(unit, inp, words), self.policy, 0.0)
        self._writes: dict[tuple[int, tuple[int, ...]], Exchange] = {}  # the last few FC16s, made once each

    def transactions(self, out_words: Sequence[int | None]) -> list[Exchange]:
        """An FC16 per run of words to write (None: leave that register alone), then the read of the inputs."""
        out: list[Exchange] = []
        start, count = 0, len(out_words)
        while start < count:
            if out_words[start] is None:
                start += 1
                continue
            end = start
            while end < count and out_words[end] is not None:
                end += 1
            out.append(self._write(start, tuple(out_words[start:end])))  # type: ignore[arg-type]  # no None here
            start = end
        out.append(self.read)
        return out

    def _write(self, offset: int, values: tuple[int, ...]) -> Exchange:
        key = (offset, values)
        exchange = self._writes.get(key)
        if exchange is None:
            if len(self._writes) >= 16:  # a changing PKW word: keep the cache small
                self._writes.clear()
            request = WriteRegistersRequest(self.unit, self.out + offset, values)
            exchange = self._writes[key] = Exchange(request, self.policy, 0.0)
        return exchange

    def read_outputs(self) -> Exchange:
        """The FC03 read of the output area (to adopt the control word in force on open)."""
        return Exchange(ReadRequest(self.unit, self.out, self.words), self.policy, 0.0)

    def inputs(self, tickets: Sequence[Ticket[Exchange, Response]]) -> tuple[int, ...]:
        """The registers the last ticket read, once every ticket ended DONE; else the first error, typed."""
        for ticket in tickets:
            if ticket.state is not TicketState.DONE:
                if ticket.error is not None:
                    raise ticket.error
                raise TransportError(f"{self.connection.driver.name}: {describe(ticket.request.request)}: withdrawn")
            response = ticket.result
            if isinstance(response, ExceptionResponse):
                code = response.code
                raise RemoteDeviceError(
                    "modbus-tcp",
                    code,
                    STANDARD_EXCEPTION_TEXTS.get(code, "unknown exception"),
                    detail=f"{self.connection.driver.name}: unit {self.unit}: {describe(ticket.request.request)}",
                )
        response = tickets[-1].result
        assert isinstance(response, ReadResponse)  # checked against its request by the decoder
        if len(response.values) != self.words:  # pragma: no cover - the decoder checks the count
            raise DecodeError(f"{self.connection.driver.name} returned {len(response.values)} registers")
        return response.values

    def exchange(self, out_words: Sequence[int | None], what: str) -> tuple[int, ...]:
        """One exchange, waited for (outside the loop)."""
        return self.inputs(self.connection.run(self.transactions(out_words), what))

    def read_now(self, exchange: Exchange, what: str) -> tuple[int, ...]:
        """One read, waited for (outside the loop)."""
        return self.inputs(self.connection.run([exchange], what))


class StationDriver(Driver[StationEngine]):
    """A station's :class:`StationEngine` on its gateway's connection (no descriptor of its own): each exchange it
    writes goes to :meth:`GatewayDriver.exchange`; its end comes back through :meth:`answer`."""

    def __init__(
        self,
        name: str,
        make_engine: Callable[[], StationEngine],
        gateway: GatewayStation,
    ) -> None:
        super().__init__(name, make_engine)
        self.gateway = gateway
        self._answers: list[tuple[DpOut, tuple[int, ...] | StarterbusError]] = []

    @property
    def deadline(self) -> float:
        return -math.inf if self._answers else self.engine.deadline

    def answer(self, unit: DpOut, words: tuple[int, ...] | StarterbusError) -> None:
        """How the exchange ``unit`` ended (from the connection's step): taken at this driver's next step."""
        self._answers.append((unit, words))

    def step(self, now: float, ready: bool) -> None:
        if self._answers:
            answers, self._answers = self._answers, []
            engine = self.engine
            for unit, words in answers:
                if isinstance(words, StarterbusError):
                    engine.refused(unit, words, now)
                else:
                    engine.receive((unit[0], words), now)  # a DpIn (typed as the unit out: see StationEngine)
        super().step(now, False)

    def write(self, units: Sequence[DpOut], now: float) -> None:
        connection = self.gateway.connection.driver
        for unit in units:
            connection.exchange(self, unit, now)
