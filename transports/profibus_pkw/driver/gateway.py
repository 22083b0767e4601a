"""A Profibus master gateway reached over Modbus TCP, on the one I/O engine (docs/engine.md, step 6).

One connection per gateway ``HOST:PORT`` in the process (``modbus``'s :class:`MbapConnection`, pooled in its
``CONNECTIONS``: an :class:`MbapEngine` on an :class:`MbapDriver` of the process's scheduler; no thread, no pymodbus
client), shared by every station mapped on the gateway and by ``modbus-tcp`` devices reached at the same
``HOST:PORT``. The stations need one transaction on the wire at a time (``outstanding=1``). One DP exchange of a
station is a batch of Modbus transactions: an FC16 per run of output words to write (a ``None`` word is left alone:
passive PZD), then the FC03 or FC04 read of its input words. The engine sends one transaction at a time, in the
order they were queued, so the stations take turns and a station's read always follows its own writes; the first
transaction that fails or is refused withdraws the rest of its batch.

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

from starterbus.core import (
    DecodeError,
    Driver,
    RemoteDeviceError,
    StarterbusError,
    Ticket,
    TicketState,
    TransportError,
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
from starterbus.transports.modbus.driver.mbap_driver import Ended
from starterbus.transports.modbus.driver.tcp_line import MbapConnection
from starterbus.transports.modbus.master.exchange import Exchange, TransactionPolicy
from starterbus.transports.profibus_pkw.master.station import DpOut, StationEngine

__all__ = ["GatewayStation", "StationDriver"]


def describe(request: Request) -> str:
    """What a transaction asks, in messages."""
    if isinstance(request, WriteRegistersRequest):
        return f"FC16 write {len(request.values)} registers at {request.address}"
    assert isinstance(request, ReadRequest)
    return f"FC{request.function:02d} read {request.count} registers at {request.address}"


class GatewayStation:
    """One station's register map on a gateway: the transactions of an exchange and the inputs of their answers.
    ``words``: the PPO's words per direction."""

    def __init__(
        self,
        connection: MbapConnection,
        words: int,
        *,
        out: int,
        inp: int,
        unit: int,
        input_function: int,
        timeout: float,
    ) -> None:
        self.connection, self.words = connection, words
        self.out, self.inp, self.unit = out, inp, unit
        # one attempt each (the PKW engine repeats its task; a status read takes the next exchange); retry_writes
        # only keeps the Modbus engine's messages from pointing a failed write at a URL parameter PKW has not
        self.policy = TransactionPolicy(timeout=timeout, retries=0, retry_writes=True)
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

    def answer(self, tickets: Sequence[Ticket[Exchange, Response]]) -> tuple[int, ...] | StarterbusError:
        """:meth:`inputs`, or the error that ended the exchange."""
        try:
            return self.inputs(tickets)
        except StarterbusError as exc:
            return exc

    def exchange(self, out_words: Sequence[int | None], what: str) -> tuple[int, ...]:
        """One exchange, waited for (outside the loop)."""
        return self.inputs(self.connection.tickets(self.transactions(out_words), what))

    def read_now(self, exchange: Exchange, what: str) -> tuple[int, ...]:
        """One read, waited for (outside the loop)."""
        return self.inputs(self.connection.tickets([exchange], what))


class StationDriver(Driver[StationEngine]):
    """A station's :class:`StationEngine` on its gateway's connection (no descriptor of its own): each exchange it
    writes goes to the connection's driver as one batch (:meth:`MbapDriver.submit_then`); its end comes back through
    :meth:`answer`."""

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
        gateway = self.gateway
        driver = gateway.connection.driver
        for unit in units:
            driver.submit_then(gateway.transactions(unit[1]), now, self._told(unit))

    def _told(self, unit: DpOut) -> Ended:
        """How the connection tells this station that its exchange ``unit`` ended."""
        gateway = self.gateway
        return lambda tickets: self.answer(unit, gateway.answer(tickets))
