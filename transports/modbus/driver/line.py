"""One RTU line (a serial port, or a TCP connection to a serial device server) and its transactions.

A :class:`RtuLine` is shared by every device on it in one process (through a :class:`SharedPool`); its lock
makes one request + answer at a time, whatever thread asks. It is the thin driver around two sans-IO parts:
the :class:`~starterbus.transports.modbus.master.guard.LineGuard`, which says when a request may start and whether an
answer may be delivered (silence, quarantine, trailing bytes, wire time), and the prepared
:class:`~starterbus.transports.modbus.master.exchange.Exchange`, which knows the exact length of the answer and
decodes it. It reads exactly the predicted length (the 5-byte header first, which is a whole frame for an
exception) and retries within the policy it is given.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import cast

from starterbus.core import (
    ConfigurationError,
    DecodeError,
    StarterbusError,
    TicketState,
    TimeoutError,
    TransportCounters,
    TransportError,
    process_scheduler,
)
from starterbus.transports.modbus.codec.messages import Request, Response
from starterbus.transports.modbus.codec.receiver import NEED_DATA, ResponseReceiver
from starterbus.transports.modbus.codec.timing import char_time
from starterbus.transports.modbus.driver.link import Link, SerialSettings, TcpConnect
from starterbus.transports.modbus.driver.rtu_driver import RtuDriver, RtuJobDriver
from starterbus.transports.modbus.master.exchange import Exchange, TransactionPolicy
from starterbus.transports.modbus.master.guard import LineGuard, hex_bytes
from starterbus.transports.modbus.master.rtu_engine import RtuTicket

__all__ = ["Exchange", "Link", "RtuLine", "SerialSettings", "TransactionPolicy"]

_DONE, _FAILED = TicketState.DONE, TicketState.FAILED  # (an Enum class's attributes are slow to read)

#: the outer bound of a blocking caller's wait for its ticket beyond the transaction's own times: only a stalled
#: loop gets there
STALL = 30.0


class RtuLine:
    """One line, shared by every device on it in this process. Thread-safe; one transaction at a time."""

    def __init__(
        self,
        connect: Callable[[], Link],
        settings: SerialSettings,
        clock: Callable[[], float] = time.monotonic,
        start_connect: Callable[[], TcpConnect] | None = None,
    ) -> None:
        self._connect = connect
        self._start_connect = start_connect  # a TCP line: reconnected by the loop without blocking (reopen)
        self._connecting: TcpConnect | None = None
        self._clock = clock
        self.link = connect()
        self._name = self.link.name
        #: a transport error broke the link, or it is closed: the next transaction reopens / reconnects it (a plain
        #: attribute: the fleet's poll reads it at every step)
        self.broken = False
        self._closed = False
        self.settings = settings
        self.lock = threading.Lock()
        self.char_time = char_time(settings.baudrate)
        self._silence = settings.silence
        self._silences = 2 * settings.silence  # after the request and after the answer
        check = settings.wire_check if settings.wire_check is not None else self.link.real_serial
        self.guard = LineGuard(settings.silence, settings.min_char_time if check else 0.0, self.char_time)
        self.transactions = 0
        self.retries = 0
        self.requests = 0  # frames written
        self._loop = process_scheduler()
        #: the blocking callers' transactions as tickets of the scheduler, while its own thread runs the loop
        self.jobs = RtuJobDriver(self, self._loop)
        #: the fleet's polls' driver (``LineTask``): its engine shares the guard; the lock makes its user one task
        #: at a time
        self.polls = RtuDriver(self)

    @property
    def name(self) -> str:
        return self._name

    @property
    def clock(self) -> Callable[[], float]:
        return self._clock

    def mark_broken(self) -> None:
        self.broken = True

    def check_settings(self, settings: SerialSettings) -> None:
        if settings != self.settings:
            raise ConfigurationError(
                f"{self.name} is already open in this process with {self.settings.describe()} "
                f"(silence {self.settings.silence * 1000:.2f} ms); a second device on the line asks for "
                f"{settings.describe()} (silence {settings.silence * 1000:.2f} ms): one line has one setting"
            )

    def close(self) -> None:
        with self.lock:
            self._closed = self.broken = True
            self._stop_connecting()
            self.link.close()

    def usable_link(self) -> Link:
        """The link, reopened (serial) or reconnected (TCP) if a transport error broke it."""
        if self._closed:
            raise TransportError(f"{self.name} is closed")
        if self.broken:
            self._stop_connecting()
            self.link.close()
            self.link = self._connect()
            self.broken = False
        return self.link

    def reopen(self) -> bool:
        """:meth:`usable_link` for the I/O loop, which must not block: a TCP line's connection is made without
        waiting (True once the link is usable, False while it is being made: ask again soon; a
        :class:`TransportError` if it cannot be). A serial port opens at once. Called by the line's holder."""
        if self._closed or not self.broken or self._start_connect is None:
            self.usable_link()
            return True
        connecting = self._connecting
        if connecting is None:
            self.link.close()
            connecting = self._connecting = self._start_connect()
        try:
            link = connecting.link()
        except TransportError:
            self._connecting = None
            raise
        if link is None:
            return False
        self._connecting = None
        self.link = link
        self.broken = False
        return True

    def _stop_connecting(self) -> None:
        connecting, self._connecting = self._connecting, None
        if connecting is not None:
            connecting.close()

    def _wait_quiet(self, exchange: Exchange) -> float:
        """Wait until the guard lets the next request start, then discard the input. Bytes seen meanwhile (a
        late answer to an earlier request, noise) quarantine the line again. Returns the time the wait ended."""
        guard, link, clock = self.guard, self.link, self._clock
        now = clock()
        give_up = now + exchange.quiet_limit
        while True:
            wait = guard.quiet_at - now
            if wait > 0:
                if now >= give_up:
                    raise self.never_silent(exchange)
                ready = link.wait_readable(min(wait, give_up - now))
                data = link.take_input() if ready else b""
                now = clock()
                if not data:
                    guard.found_empty(now)
                    continue
            elif not guard.must_discard(now):  # found empty a moment ago (the silence after the last answer)
                return now
            else:
                data = link.take_input()  # input is discarded before each send
                if not data:
                    return now
                now = clock()
            guard.stray(data, now, exchange.quarantine)

    def never_silent(self, exchange: Exchange) -> TransportError:
        return TransportError(
            f"{self.name}: the line did not fall silent within {exchange.quiet_limit:g} s "
            f"(last bytes {hex_bytes(self.guard.last_stray)})"
        )

    def prepare(self, request: Request, policy: TransactionPolicy) -> Exchange:
        """``request`` made ready for :meth:`run` (encoded and checked: an invalid request raises here)."""
        return Exchange(request, policy, self.char_time)

    def transact(self, request: Request, policy: TransactionPolicy) -> Response | None:
        """Send ``request`` and return the checked answer (an ExceptionResponse is an answer, not an error).

        Broadcasts return None. Raises TimeoutError / DecodeError after the allowed attempts: reads are
        retried ``policy.retries`` times; a write only if ``policy.retry_writes`` (it may have been executed).
        """
        return self.run(self.prepare(request, policy))

    def run(self, exchange: Exchange, counters: TransportCounters | None = None) -> Response | None:
        """:meth:`transact` for a prepared request (the same exchange may be run any number of times); what the
        transaction put on the wire is added to ``counters`` (the asking transport's: the line serialises).

        Each attempt: wait until the guard lets the request start, write it, read the answer (at least the header
        and at most the whole answer in the first read: on a pty, usually all of it; anything but a whole good
        answer goes on in :meth:`_receive_rest`), then deliver it only if the guard lets it through: not sooner
        than the wire allows, and followed by silence (the silent interval's wait is here, not before the next
        request). The usual case runs in this one function: it is every transaction's CPU.

        While the scheduler's own thread runs the loop (a service), the transaction is a ticket of the line's
        :class:`RtuJobDriver` instead, run by that thread under the same guard (a line without a descriptor,
        pyserial's, stays with its caller); from inside the loop that is refused (``SchedulerReentryError``).
        """
        if self._loop.thread is not None and self.link.fd >= 0:
            return self._follow(exchange, counters)
        with self.lock:  # not acquire()/try/finally: a KeyboardInterrupt right after acquire() would leak the lock
            self.transactions += 1
            attempt = 0
            try:
                if self.broken:
                    self.usable_link()
                guard, link, clock = self.guard, self.link, self._clock
                while True:
                    attempt += 1
                    started = clock()  # no later than the request's first byte
                    if not guard.send_now(started):
                        started = self._wait_quiet(exchange)
                        guard.sent(started)
                    self.requests += 1
                    if exchange.broadcast:
                        link.write(exchange.frame)
                        guard.broadcast_sent(clock(), exchange.wire, exchange.policy.turnaround)
                        if counters is not None:
                            self.count(counters, exchange, attempt, 0, None)
                        return None
                    try:
                        deadline, length = started + exchange.budget, exchange.answer_length
                        data = link.transfer(exchange.frame, exchange.header_length, deadline, length, exchange.budget)
                        at = clock()
                        response = exchange.quick_decode(data) if len(data) == length else None
                        if response is None:
                            data, response, at = self._receive_rest(exchange, data, at, deadline)
                        error = guard.answer_complete(exchange.frame_length, data, at)
                        if error is not None:
                            raise error
                        try:
                            extra = link.take_input() if link.wait_readable(guard.trail_until - at) else b""
                        except TransportError:  # the connection closed after the answer: no byte followed it
                            self.broken = True
                            extra = b""
                        if extra:
                            raise guard.trailing(data, extra)
                        guard.delivered(data)
                        if counters is not None and attempt == 1:  # count() for the usual case, written out
                            sent, received = exchange.frame_length, len(data)
                            counters.transactions += 1
                            counters.requests += 1
                            counters.bytes_sent += sent
                            counters.bytes_received += received
                            counters.wire_time += (sent + received) * self.char_time + self._silences
                        elif counters is not None:
                            self.count(counters, exchange, attempt, len(data), None)
                        return response
                    except (TimeoutError, DecodeError) as exc:
                        self.failed(exchange, exc, attempt)
            except StarterbusError as exc:
                self.given_up(counters, exchange, attempt, exc)
                raise

    def _follow(self, exchange: Exchange, counters: TransportCounters | None) -> Response | None:
        """The transaction as a ticket of :attr:`jobs`, waited for in the caller's thread."""
        bound = STALL + exchange.quiet_limit + exchange.attempts * (exchange.budget + exchange.quarantine)
        what = f"{self.name}: unit {exchange.request.unit}"
        (ended,) = self._loop.run(self.jobs, (exchange,), bound, what)
        ticket = cast(RtuTicket, ended)
        if counters is not None:
            self.count_ticket(counters, ticket)
        return ticket.outcome()

    def count_ticket(self, counters: TransportCounters, ticket: RtuTicket) -> None:
        """What an ended (or cancelled) ticket's transaction put on the wire, into ``counters``."""
        exchange, state = ticket.request, ticket.state
        if state is _DONE:
            received = ticket.received
            if ticket.attempts == 1 and received:  # count() for the usual case, written out (as in run)
                sent = exchange.frame_length
                counters.transactions += 1
                counters.requests += 1
                counters.bytes_sent += sent
                counters.bytes_received += received
                counters.wire_time += (sent + received) * self.char_time + self._silences
                return
            self.count(counters, exchange, ticket.attempts, received, None)
        elif state is _FAILED:
            self.count(counters, exchange, max(1, ticket.attempts), 0, ticket.error)
        elif ticket.attempts:
            self.count(counters, exchange, ticket.attempts, 0, None)

    def broke(self, exc: StarterbusError) -> None:
        """A transaction failed for good with ``exc``: a transport error breaks the link (reopened / reconnected
        before the next transaction)."""
        if isinstance(exc, TransportError) and not isinstance(exc, TimeoutError):
            self.broken = True

    def given_up(
        self, counters: TransportCounters | None, exchange: Exchange, attempt: int, exc: StarterbusError
    ) -> None:
        """The transaction failed for good with ``exc`` after ``attempt`` attempts: a transport error breaks the
        link (reopened / reconnected before the next transaction); counted in ``counters``."""
        self.broke(exc)
        if counters is not None:
            self.count(counters, exchange, max(1, attempt), 0, exc)

    def count(
        self, c: TransportCounters, exchange: Exchange, sent: int, received: int, failure: StarterbusError | None
    ) -> None:
        """Count one transaction: ``sent`` frames (repeats included), the ``received`` bytes of the answer it
        delivered (0: none), the wire time at the line's speed with a silence after every frame."""
        c.transactions += 1
        c.requests += sent
        c.retries += sent - 1
        c.timeouts += isinstance(failure, TimeoutError)
        c.errors += received == 0 and not exchange.broadcast
        c.bytes_sent += sent * len(exchange.frame)
        c.bytes_received += received
        c.wire_time += (sent * len(exchange.frame) + received) * self.char_time + 2 * sent * self._silence

    def failed(self, exchange: Exchange, exc: TimeoutError | DecodeError, attempt: int) -> None:
        """Attempt ``attempt`` failed with ``exc``: the line is quarantined; raise ``exc`` if it was the last."""
        self.guard.failed(self._clock(), exchange.quarantine)  # the next request waits the quarantine
        if exchange.last_attempt(exc, attempt):
            raise exc
        self.retries += 1

    def _receive_rest(
        self, exchange: Exchange, data: bytes, last_rx: float, deadline: float
    ) -> tuple[bytes, Response, float]:
        """Anything but a whole good answer in the first read: (the answer, its decoding, when it was complete).

        ``data`` is what the first read gave (at least the header unless the time ran out). The rest of a normal
        answer is one more read; anything unusual goes to the receiver, which checks each piece and names what
        is wrong.
        """
        needed, length = exchange.header_length, exchange.answer_length
        if needed <= len(data) < length and exchange.good_so_far(data):
            rest = self.link.read(length - len(data), deadline)
            if rest:
                data += rest
                last_rx = self._clock()
            if len(data) == length:
                response = exchange.quick_decode(data)
                if response is not None:
                    return data, response, last_rx
        receiver = ResponseReceiver(exchange.request)
        while True:
            if needed:  # ``data`` is what a read of at least ``needed`` bytes gave
                if data:
                    receiver.feed(data)
                event = receiver.next_event()
                if event is NEED_DATA and len(data) < needed:
                    if receiver.received:
                        raise receiver.truncated_error()
                    raise exchange.no_answer(self.name)
            else:
                event = receiver.next_event()
            if event is not NEED_DATA:
                if receiver.trailing:  # an exception answer read together with what followed it
                    raise self.guard.trailing(receiver.frame, receiver.trailing)
                return receiver.frame, event, last_rx
            needed = receiver.bytes_needed()
            if needed:
                data = self.link.read(needed, deadline, receiver.expected_length - len(receiver.received))
                if data:
                    last_rx = self._clock()
