"""One Modbus TCP connection to a gateway (or a TCP device), shared by everything this process reaches at that
``HOST:PORT`` (:data:`CONNECTIONS`): the units of ``modbus-tcp`` devices behind it and Profibus PKW gateway
stations mapped on it.

The connection is :class:`~starterbus.transports.modbus.master.mbap.MbapEngine` on an
:class:`~starterbus.transports.modbus.driver.mbap_driver.MbapDriver`, run by the process's scheduler
(docs/engine.md): no thread of its own. A caller submits its transactions and waits for their tickets; while no
other thread runs the loop, the caller runs it (one ``select`` for the answer, in its own thread). At most
``outstanding`` transactions are on the wire at once (the engine queues the others). A transaction that times out is
forgotten: its late answer is stale and dropped. A 0x0A / 0x0B exception is the gateway saying the device behind it
is unreachable: a failed attempt like a timeout (retried within the policy), never a refusal. A broken connection
fails every sent transaction; the next request reconnects, after a backoff if connecting failed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Future
from typing import Any

from starterbus.core import (
    PollResult,
    PollTask,
    Scheduler,
    SharedPool,
    StarterbusError,
    TicketState,
    TimeoutError,
    TransportCounters,
    TransportError,
    address_of,
    process_scheduler,
)
from starterbus.transports.modbus.codec.messages import Response
from starterbus.transports.modbus.driver.mbap_driver import MbapDriver
from starterbus.transports.modbus.master.exchange import Exchange
from starterbus.transports.modbus.master.mbap import HEADER_LENGTH, MbapTicket

#: the outer bound of a wait beyond the transactions' own timeouts: only a stalled loop gets there
STALL = 30.0
#: how soon a poll looks again while another thread runs the loop (that thread serves the poll meanwhile)
LOOK_AGAIN = 0.001
#: how soon a poll advanced from the loop's own thread looks again without news (its futures' callbacks have it
#: advanced as soon as a transaction ends: this only bounds a wait)
LOOK_LATER = 1.0


#: one connection per ``HOST:PORT`` in this process, shared by everything reached there: ``modbus-tcp`` devices and
#: Profibus PKW gateway stations (:func:`connection_key`)
CONNECTIONS: SharedPool[MbapConnection] = SharedPool("Modbus TCP connections")


def connection_key(host: str, port: int) -> tuple[str, str, int]:
    """The key of the connection to ``host:port`` in :data:`CONNECTIONS`."""
    return ("modbus-tcp", host, port)


class MbapConnection:
    """A Modbus TCP client connection; thread-safe. ``run`` has the signature of ``RtuLine.run``. ``connect``:
    connect now and raise if that fails (else on the first transaction). ``outstanding`` and ``connect_timeout``
    are the connection's own: whoever opens it first sets them."""

    def __init__(
        self,
        host: str,
        port: int,
        outstanding: int,
        connect_timeout: float,
        loop: Scheduler | None = None,
        *,
        connect: bool = True,
    ) -> None:
        self.host, self.port = host, port
        self.outstanding = outstanding
        self.connect_timeout = connect_timeout
        self.loop = loop or process_scheduler()
        self.driver = MbapDriver(host, port, outstanding, connect_timeout)
        self.name = self.driver.name
        try:  # here, in the opener's thread: the loop never waits on a name server
            address_of(host, port)
        except OSError as exc:
            raise TransportError(f"cannot connect to {self.name}: cannot look up {host!r}: {exc}") from exc
        opened = self._call(self._open if connect else self._add, "connect")
        if connect:
            try:
                self.loop.wait(opened, connect_timeout + STALL, f"{self.name}: connect")
            except StarterbusError:
                self.close()
                raise

    def _add(self, now: float) -> None:
        self.loop.add(self.driver)

    def _open(self, now: float) -> Future[None]:
        self.loop.add(self.driver)
        return self.driver.open(now)

    def _call(self, fn: Callable[[float], Any], what: str) -> Any:
        return self.loop.wait(self.loop.call(fn), STALL, f"{self.name}: {what}")

    def close(self) -> None:
        driver = self.driver

        def close(now: float) -> None:
            self.loop.remove(driver)
            driver.close(now)

        self._call(close, "close")

    @property
    def stale(self) -> int:
        """Answers dropped because no transaction waited for their id."""
        return self.driver.engine.stale

    @property
    def connects(self) -> int:
        """Connections made so far."""
        return self.driver.connects

    def check(self) -> bool:
        """Whether the connection is up, after taking what waits on it (a close by the gateway is seen)."""
        return bool(self._call(self.driver.check, "check"))

    # -- transactions ---------------------------------------------------------------------------------------------

    def run(self, exchange: Exchange, counters: TransportCounters | None = None) -> Response | None:
        """One transaction with the policy's attempts (reads retried, writes only with ``retry_writes``)."""
        return self.run_many([exchange], counters)[0]

    def run_many(self, exchanges: Sequence[Exchange], counters: TransportCounters | None = None) -> list[Response]:
        """The transactions, up to ``outstanding`` on the wire at once; answers in the order of ``exchanges``, up to
        the first refusal (an exception answer withdraws the transactions after it). A failed attempt is repeated on
        its own, within its policy; the first failure for good raises (the transactions after it are withdrawn:
        those not sent never are)."""
        if not exchanges:
            return []
        tickets = self.tickets(exchanges, f"unit {exchanges[0].request.unit}")
        for exchange, ticket in zip(exchanges, tickets, strict=False):
            if ticket.state is not TicketState.CANCELLED:  # withdrawn after another one's failure or refusal
                self._count(counters, exchange, ticket)
        for ticket in tickets:
            if ticket.state is TicketState.FAILED:
                ticket.outcome()  # raises its error
        answers: list[Response] = []
        for ticket in tickets:
            if ticket.state is TicketState.CANCELLED:
                break
            answers.append(ticket.outcome())
        return answers

    def tickets(self, exchanges: Sequence[Exchange], what: str) -> list[MbapTicket]:
        """The transactions as one batch, waited for (a blocking call: outside the loop): their ended tickets."""
        bound = STALL + self.connect_timeout + sum(e.policy.timeout * e.attempts for e in exchanges)
        return self.loop.run(self.driver, exchanges, bound, f"{self.name}: {what}")  # type: ignore[return-value]

    def _withdraw(self, futures: Sequence[Future[Any]]) -> None:
        """Cancel these futures' transactions (without waiting: the loop does it at its next turn)."""
        if futures:
            driver = self.driver
            self.loop.call(lambda now: driver.cancel(futures, now))

    def _count(self, counters: TransportCounters | None, exchange: Exchange, ticket: MbapTicket) -> None:
        if counters is None:
            return
        failure = ticket.error
        sent, received = ticket.attempts, ticket.received
        request_bytes = HEADER_LENGTH + len(exchange.frame) - 3  # MBAP header + PDU (no unit byte, no CRC)
        counters.transactions += 1
        counters.requests += sent
        counters.retries += max(0, sent - 1)
        counters.timeouts += isinstance(failure, TimeoutError)
        counters.errors += failure is not None
        counters.bytes_sent += sent * request_bytes
        counters.bytes_received += received
        if ticket.sent_at is not None and ticket.done_at is not None:
            counters.busy_time += ticket.done_at - ticket.sent_at
        # the time the requests and the answer take on the serial line behind the gateway (RTU framing)
        char = exchange.wire / len(exchange.frame)
        counters.wire_time += sent * exchange.wire + (exchange.answer_length * char if received else 0.0)


class MbapPoll(PollTask):
    """A poll's transactions as a :class:`PollTask`: submitted at the first :meth:`advance`. Advanced from the
    scheduler's own loop (the fleet sets :attr:`on_progress`), it is advanced again when one of its transactions
    ends; advanced from elsewhere, each advance is one turn of the scheduler without waiting (the caller waits on
    the connection's descriptor and deadline for it). ``check`` refuses an answer (an exception), ``finish``
    makes the poll's result from the answers."""

    def __init__(
        self,
        connection: MbapConnection,
        exchanges: Sequence[Exchange],
        counters: TransportCounters,
        check: Callable[[Exchange, Response], None],
        finish: Callable[[list[Response]], PollResult],
    ) -> None:
        self.connection, self.exchanges, self.counters = connection, exchanges, counters
        self.check, self.finish = check, finish
        self._futures: list[Future[Any]] | None = None
        self._responses: list[Response] = []
        self._result: PollResult | None = None
        self._error: StarterbusError | None = None

    def advance(self, now: float) -> None:
        if self.done:
            return
        connection = self.connection
        loop, driver = connection.loop, connection.driver
        progress = self.on_progress
        if self._futures is None:
            self._futures = loop.submit_all(driver, self.exchanges)
            if progress is not None:  # advanced again when a transaction ends (in the loop's thread)
                for future in self._futures:
                    future.add_done_callback(lambda _: progress())
        if progress is not None:  # the loop that ends the futures is the one that advances this task
            self.fd, self.wake_at = -1, now + LOOK_LATER
        elif loop.try_turn():
            self.fd, self.wake_at = driver.fd, driver.deadline
        else:
            self.fd, self.wake_at = -1, now + LOOK_AGAIN
        futures = self._futures
        while len(self._responses) < len(futures) and futures[len(self._responses)].done():
            index = len(self._responses)
            exchange = self.exchanges[index]
            ticket: MbapTicket = futures[index].result()
            connection._count(self.counters, exchange, ticket)
            try:
                response = ticket.outcome()
                self.check(exchange, response)
            except StarterbusError as exc:
                self._end(exc, futures[index + 1 :])
                return
            self._responses.append(response)
        if len(self._responses) == len(futures):
            try:
                self._result = self.finish(self._responses)
            except StarterbusError as exc:
                self._error = exc
            self.done = True

    def _end(self, error: StarterbusError, rest: Sequence[Future[Any]]) -> None:
        self._error = error
        self.done = True
        self.connection._withdraw(rest)
        self.connection.loop.try_turn()  # the withdrawal made now, unless another thread leads (it makes it)

    def result(self) -> PollResult:
        if self._error is not None:
            raise self._error
        if self._result is None:
            raise TransportError(f"{self.connection.name}: the poll was cancelled")
        return self._result

    def cancel(self) -> None:
        if not self.done:
            self._end(TransportError(f"{self.connection.name}: the poll was cancelled"), self._futures or [])
