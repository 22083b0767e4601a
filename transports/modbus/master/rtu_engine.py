"""One RTU line's transactions as a sans-IO :class:`~starterbus.core.engine.Engine` (docs/engine.md, step 3).

What :class:`~starterbus.transports.modbus.driver.line_task.LineTask` did, without its I/O, its clock and its lock: a
request is a prepared :class:`~starterbus.transports.modbus.master.exchange.Exchange`, its ticket ends with the
checked answer (an exception answer is an answer) or the error after the attempts the policy allows. The rules
are the :class:`~starterbus.transports.modbus.master.guard.LineGuard`'s, shared with the blocking
:meth:`RtuLine.run <starterbus.transports.modbus.driver.line.RtuLine.run>`: silence (or the quarantine) before a
request, input looked at just before it, not faster than the wire, the trailing silence, the quarantine after a
failed attempt. The steps: START (the next request may go out at ``take_output``), QUIET (waiting for the
silence; bytes meanwhile are stray), ANSWER (reading), TRAIL (the silence after the answer).

Times: ``take_output(now)``: the clock read just before the write (the request counts as started then);
``receive(data, at)``: a reading taken after ``data`` was read (an answer is complete then);
``receive(None, at)``: the input was looked at, at ``at``, and found empty (the silence rule needs it).
"""

from __future__ import annotations

import enum
from collections import deque
from collections.abc import Callable, Sequence

from starterbus.core import FOREVER, DecodeError, StarterbusError, Ticket, TimeoutError, TransportError
from starterbus.transports.modbus.codec.messages import Response
from starterbus.transports.modbus.codec.receiver import NEED_DATA, ResponseReceiver
from starterbus.transports.modbus.master.exchange import Exchange
from starterbus.transports.modbus.master.guard import LineGuard, hex_bytes

__all__ = ["ANSWER", "IDLE", "QUIET", "START", "TRAIL", "Phase", "RtuEngine", "RtuTicket"]

#: bytes read at most when no answer is being read
READ_CHUNK = 512
#: QUIET: how soon the input is asked for again when the driver did not look (a driver that looks before every
#: step never waits for it)
LOOK_AGAIN = 0.0001

_Handler = Callable[[Exchange, bytes, float], None]  # an attempt's step


class Phase(enum.Enum):
    IDLE = "idle"
    START = "start"
    QUIET = "quiet"
    ANSWER = "answer"
    TRAIL = "trail"


# module constants, compared by identity: an Enum class's attribute goes through the enum type's __getattr__ hook
# (read at every step; a driver reads ``RtuEngine.phase`` against these)
IDLE, START, QUIET, ANSWER, TRAIL = Phase.IDLE, Phase.START, Phase.QUIET, Phase.ANSWER, Phase.TRAIL
_IDLE, _START, _QUIET, _ANSWER, _TRAIL = IDLE, START, QUIET, ANSWER, TRAIL


class RtuTicket(Ticket[Exchange, "Response | None"]):
    """An exchange's ticket, with what the line counts: the bytes of the answer delivered (0: none)."""

    __slots__ = ("received",)

    def __init__(self, exchange: Exchange) -> None:
        super().__init__(exchange)
        self.received = 0


class RtuEngine:
    """The transactions of one line, one at a time, in the order submitted. ``guard``: the line's (shared with
    the blocking driver); ``name``: the line's, for the errors."""

    def __init__(self, guard: LineGuard, name: str) -> None:
        self.guard = guard
        self.name = name
        self._queue: deque[RtuTicket] = deque()
        self._current: RtuTicket | None = None
        self.phase = _IDLE  # the step the engine is at (a plain attribute: its driver reads it at every step)
        self._stray = b""  # bytes seen while no request was under way: discarded at the next start
        self._give_up = 0.0  # QUIET: when waiting for silence becomes an error
        self._look_at = 0.0  # QUIET, silent long enough: when to ask again for a look at the input
        self._deadline = 0.0  # ANSWER: when the answer is late
        self._data = b""  # ANSWER: what arrived (while it looks like a normal answer)
        self._receiver: ResponseReceiver | None = None  # ANSWER: anything else
        self._at = 0.0  # when the last byte of the answer so far was read
        self._empty_at = 0.0  # TRAIL: when the input was last found empty
        self._answer: tuple[bytes, Response] | None = None  # TRAIL
        self._completed: list[RtuTicket] = []
        self.transactions = 0
        self.requests = 0  # frames written
        self.retries = 0

    # -- what a driver reads -------------------------------------------------------------------------------------

    @property
    def deadline(self) -> float:
        step = self.phase
        if step is _ANSWER:
            return self._deadline
        if step is _TRAIL:
            return self.guard.trail_until
        if step is _START:
            return -FOREVER  # due now: take_output sends or starts waiting
        if step is _QUIET:
            return min(max(self.guard.quiet_at, self._look_at), self._give_up)
        return FOREVER

    @property
    def answering(self) -> Exchange | None:
        """The exchange whose answer is being read (a driver may look later on a pty: see ``LineTask``)."""
        return self._current.request if self.phase is _ANSWER and self._current is not None else None

    @property
    def answer_so_far(self) -> tuple[int, float]:
        """ANSWER: the bytes of a normal answer read so far, and when the last came (0 once it is unusual)."""
        return (0 if self._receiver is not None else len(self._data)), self._at

    @property
    def want(self) -> int:
        """How many bytes to read at most: the rest of the answer while one is read (the bytes after it are
        read when its silence is watched), else :data:`READ_CHUNK`."""
        if self.phase is _ANSWER and self._current is not None:
            receiver = self._receiver
            if receiver is None:
                return self._current.request.answer_length - len(self._data)
            return max(1, receiver.expected_length - len(receiver.received))
        return READ_CHUNK

    @property
    def trailing(self) -> bool:
        """An answer is complete and its silence is being watched."""
        return self.phase is _TRAIL

    @property
    def wants_to_send(self) -> bool:
        return self.phase is _START or self.phase is _QUIET

    def must_look(self, now: float) -> bool:
        """Whether the input must be looked at (``receive``) now: always while waiting for the silence (bytes then
        are stray), else unless it was found empty a moment ago (the silence after the last answer)."""
        return self.phase is _QUIET or self.guard.must_discard(now)

    @property
    def pending(self) -> int:
        return len(self._queue) + (self._current is not None)

    # -- the verbs -------------------------------------------------------------------------------------------

    def submit(self, request: Exchange, now: float) -> RtuTicket:
        ticket = RtuTicket(request)
        self._queue.append(ticket)
        if self.phase is _IDLE:
            self._next()
        return ticket

    def cancel(self, ticket: Ticket[Exchange, Response | None], now: float) -> None:
        if ticket.ended:
            return
        if ticket is not self._current:
            self._queue.remove(ticket)  # type: ignore[arg-type]
            self._end_cancelled(ticket, now)  # type: ignore[arg-type]
            return
        if self.phase in (_ANSWER, _TRAIL):  # an answer may still come: the line is not silent
            self.guard.failed(now, ticket.request.quarantine)
        self._end_cancelled(ticket, now)
        self._next()

    def receive(self, data: bytes | None, now: float) -> None:
        step = self.phase
        if not data:
            if data is None:
                if step is _TRAIL:
                    self._empty_at = now
                elif step is not _ANSWER and not self._stray:
                    self.guard.found_empty(now)
            return
        if step is _ANSWER:
            self._attempt(self._receive, data, now)
        elif step is _TRAIL:
            assert self._answer is not None
            self._attempt(self._trailing, data, now)
        elif step is _QUIET:
            assert self._current is not None
            self.guard.stray(data, now, self._current.request.quarantine)
        else:  # nobody's: stray, quarantined when the next request starts
            self._stray += data

    def advance(self, now: float) -> None:
        step = self.phase
        if step is _QUIET:
            if now >= self._give_up:
                assert self._current is not None
                exchange = self._current.request
                why = (
                    f"the line did not fall silent within {exchange.quiet_limit:g} s (last bytes "
                    f"{hex_bytes(self.guard.last_stray)})"
                    if self.guard.quiet_at > now
                    else f"its input was not looked at before a send within {exchange.quiet_limit:g} s"
                )
                self._given_up(TransportError(f"{self.name}: {why}"), now)
        elif step is _ANSWER:
            if now >= self._deadline:
                self._attempt(self._late, b"", now)
        elif step is _TRAIL and now >= self.guard.trail_until:
            self._deliver(now)

    def take_output(self, now: float) -> Sequence[bytes]:
        ticket, guard = self._current, self.guard
        if ticket is None:
            return ()
        exchange = ticket.request
        if self.phase is _START:
            if ticket.attempts == 0:
                self.transactions += 1
            if self._stray:
                stray, self._stray = self._stray, b""
                guard.stray(stray, now, exchange.quarantine)
            if not guard.send_now(now):
                self._give_up = now + exchange.quiet_limit
                self._look_at = now if guard.quiet_at > now else now + max(guard.fresh, LOOK_AGAIN)
                self.phase = _QUIET
                return ()
        elif self.phase is _QUIET:
            if guard.quiet_at > now:
                return ()
            if guard.must_discard(now):  # the input was not looked at just now: the driver is asked to
                self._look_at = now + max(guard.fresh, LOOK_AGAIN)
                return ()
        else:
            return ()
        guard.sent(now)
        self.requests += 1
        ticket.sent(now)
        if exchange.broadcast:
            guard.broadcast_sent(now, exchange.wire, exchange.policy.turnaround)
            ticket.done(None, now)
            self._completed.append(ticket)
            self._next()
            return (exchange.frame,)
        self._deadline = now + exchange.budget
        self._data, self._receiver = b"", None
        self._empty_at = 0.0
        self.phase = _ANSWER
        return (exchange.frame,)

    def take_completed(self) -> Sequence[RtuTicket]:
        done = self._completed
        if not done:
            return ()
        self._completed = []
        return done

    # -- one attempt -------------------------------------------------------------------------------------------

    def _attempt(self, step: _Handler, data: bytes, now: float) -> None:
        """An ANSWER or TRAIL step; a bad or missing answer fails the attempt (retried within the policy)."""
        ticket = self._current
        assert ticket is not None
        try:
            step(ticket.request, data, now)
        except (TimeoutError, DecodeError) as exc:
            self.guard.failed(now, ticket.request.quarantine)
            if ticket.request.last_attempt(exc, ticket.attempts):
                self._given_up(exc, now)
            else:
                self.retries += 1
                self.phase = _START

    def _receive(self, exchange: Exchange, chunk: bytes, at: float) -> None:
        self._at = at
        receiver = self._receiver
        if receiver is None:
            data = self._data + chunk
            length = exchange.answer_length
            if len(data) >= length:
                answer, extra = data[:length], data[length:]
                response = exchange.quick_decode(answer)
                if response is not None:
                    self._complete(exchange, answer, response, at)
                    if extra:
                        self._trailing(exchange, extra, at)
                    return
            if len(data) >= length or (len(data) >= exchange.header_length and not exchange.good_so_far(data)):
                receiver = self._receiver = ResponseReceiver(exchange.request)
                receiver.feed(data)
            else:
                self._data = data
                return
        else:
            receiver.feed(chunk)
        event = receiver.next_event()
        if event is not NEED_DATA:
            if receiver.trailing:  # an answer read together with what followed it
                raise self.guard.trailing(receiver.frame, receiver.trailing)
            self._complete(exchange, receiver.frame, event, at)

    def _late(self, exchange: Exchange, _data: bytes, _now: float) -> None:
        receiver = self._receiver
        if receiver is None:
            receiver = ResponseReceiver(exchange.request)
            receiver.feed(self._data)
        if receiver.received:
            raise receiver.truncated_error()
        raise exchange.no_answer(self.name)

    def _complete(self, exchange: Exchange, frame: bytes, response: Response, at: float) -> None:
        error = self.guard.answer_complete(exchange.frame_length, frame, at)
        if error is not None:
            raise error
        self._answer = (frame, response)
        self.phase = _TRAIL

    def _trailing(self, _exchange: Exchange, extra: bytes, _now: float) -> None:
        assert self._answer is not None
        raise self.guard.trailing(self._answer[0], extra)

    def _deliver(self, now: float) -> None:
        ticket, answer = self._current, self._answer
        assert ticket is not None and answer is not None
        frame, response = answer
        guard = self.guard
        guard.delivered(frame)
        if self._empty_at > guard.checked_at:  # found empty after the silence: no look needed before a request
            guard.found_empty(self._empty_at)
        ticket.received = len(frame)
        ticket.done(response, now)
        self._completed.append(ticket)
        self._answer = None
        self._next()

    # -- endings ---------------------------------------------------------------------------------------------

    def _given_up(self, error: StarterbusError, now: float) -> None:
        ticket = self._current
        assert ticket is not None
        ticket.failed(error, now)
        self._completed.append(ticket)
        self._next()

    def _end_cancelled(self, ticket: RtuTicket, now: float) -> None:
        ticket.cancelled(now)
        self._completed.append(ticket)

    def _next(self) -> None:
        self._current = self._queue.popleft() if self._queue else None
        self.phase = _START if self._current is not None else _IDLE
        self._answer = None
