"""A poll's transactions on one RTU line as a :class:`~starterbus.core.polling.PollTask`: what
:meth:`RtuLine.run <starterbus.transports.modbus.line.RtuLine.run>` does, without blocking.

One poller thread can then keep many lines busy (``fleet/mux.py``): it waits on every line's descriptor and
timer at once and advances the task whose input or time has come. The rules are the same sans-IO parts the
blocking driver uses, fed the same way: the :class:`~starterbus.transports.modbus.guard.LineGuard` says when a
request may start (silence, input discarded just before, quarantine) and whether an answer may be delivered
(not sooner than the wire allows, followed by silence); the :class:`~starterbus.transports.modbus.exchange.
Exchange` and the :class:`~starterbus.transports.modbus.receiver.ResponseReceiver` decode it or name what is
wrong; failures quarantine the line and are retried within the policy; the line's lock is held from a
request's start to its answer's delivery, so blocking users of the same line in this process wait their turn.

Times: a request counts as started at a clock reading taken before it is written; an answer as complete at a
reading taken after its last byte was read; the silence after it from then on. A task advanced late reads
what arrived meanwhile before it decides on a timeout (bytes after the request belong to it or to nobody: the
quarantine rules out earlier requests), and takes bytes found in the input after the silence as trailing
(the answer is dropped: an error, never a wrong value).
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Sequence

from starterbus.core.errors import DecodeError, StarterbusError, TimeoutError, TransportError
from starterbus.core.polling import PollResult, PollTask
from starterbus.core.transport import TransportCounters
from starterbus.transports.modbus.exchange import Exchange
from starterbus.transports.modbus.frames import Response
from starterbus.transports.modbus.line import RtuLine
from starterbus.transports.modbus.receiver import NEED_DATA, ResponseReceiver

#: how soon a task looks again at a line that another thread holds
LOCK_RETRY = 0.001


class _Step(enum.Enum):
    START = "start"  # take the line, then send now or wait for it to fall silent
    QUIET = "quiet"  # waiting for the silence (or the quarantine) before the request
    ANSWER = "answer"  # request written, reading the answer
    TRAIL = "trail"  # answer complete, watching the silence that must follow it
    OVER = "over"


class LineTask(PollTask):
    """``exchanges`` one after another on ``line``; ``check`` sees each answer (raising ends the task),
    ``finish`` makes the result of all of them. What goes on the wire is added to ``counters``."""

    def __init__(
        self,
        line: RtuLine,
        exchanges: Sequence[Exchange],
        counters: TransportCounters,
        check: Callable[[Exchange, Response], None],
        finish: Callable[[list[Response]], PollResult],
    ) -> None:
        if any(e.broadcast for e in exchanges):
            raise ValueError("a broadcast gets no answer: it is not a poll")
        self.line = line
        self._exchanges = exchanges
        self._counters = counters
        self._check = check
        self._finish = finish
        self._responses: list[Response] = []
        self._index = 0
        self._attempt = 0
        self._step = _Step.START if exchanges else _Step.OVER
        self._locked = False
        self._give_up = 0.0  # QUIET: when waiting for silence becomes an error
        self._deadline = 0.0  # ANSWER: when the answer is late
        self._data = b""  # ANSWER: what arrived (while it looks like a normal answer)
        self._receiver: ResponseReceiver | None = None  # ANSWER: anything else
        self._at = 0.0  # when the last byte of the answer so far was read
        self._answer: tuple[bytes, Response] | None = None  # TRAIL: the answer waiting for its silence
        self._outcome: PollResult | StarterbusError | None = None
        self.fd = -1  # nothing to watch before the line is taken (and reopened if it broke)
        self.wake_at = 0.0
        self.done = False

    # -- the PollTask interface ------------------------------------------------------------------------------

    def advance(self, now: float) -> None:
        if self.done:
            return
        try:
            self._advance(now)
        except StarterbusError as exc:
            self._end(exc)
        except BaseException:
            self._release()
            raise

    def result(self) -> PollResult:
        outcome = self._outcome
        if isinstance(outcome, PollResult):
            return outcome
        if outcome is None:
            raise RuntimeError("the poll task is not done")
        raise outcome

    def cancel(self) -> None:
        if self._step in (_Step.ANSWER, _Step.TRAIL):  # an answer may still come: the line is not silent
            exchange = self._exchanges[self._index]
            self.line.guard.failed(self.line.clock(), exchange.quarantine)
            self.line.count(self._counters, exchange, max(1, self._attempt), 0, None)
        elif self._step is _Step.QUIET and self._attempt > 1:  # a retry waiting: the attempts sent are counted
            self.line.count(self._counters, self._exchanges[self._index], self._attempt - 1, 0, None)
        self._step = _Step.OVER
        self._release()
        if not self.done:
            self._outcome = TransportError(f"{self.line.name}: poll cancelled")
            self.done = True

    # -- the steps -------------------------------------------------------------------------------------------

    def _advance(self, now: float) -> None:
        while not self.done:
            step = self._step
            if step is _Step.START:
                if not self._start():
                    self.fd = -1  # the line's input is its holder's until it is free: look again soon
                    self.wake_at = now + LOCK_RETRY
                    return
            elif step is _Step.QUIET:
                if not self._quiet(now):
                    return
            elif step is _Step.ANSWER:
                if not self._in_transaction(self._receive, now):
                    return
            elif step is _Step.TRAIL:
                if not self._in_transaction(self._trail, now):
                    return
            else:
                self._finish_all()

    def _start(self) -> bool:
        """Take the line and send now, or start waiting for silence; False: another thread holds the line."""
        line = self.line
        if not self._locked:
            if not line.lock.acquire(blocking=False):
                return False
            self._locked = True
        exchange = self._exchanges[self._index]
        if self._attempt == 0:
            line.transactions += 1
        self._attempt += 1
        try:
            link = line.usable_link() if line.broken else line.link
            self.fd = link.fd
            now = line.clock()  # fresh: whether the input was just found empty is a matter of microseconds
            if line.guard.send_now(now):
                self._send(exchange, now)
            else:
                self._give_up = now + exchange.quiet_limit
                self._step = _Step.QUIET
        except StarterbusError as exc:
            self._transaction_failed(exc)
        return True

    def _quiet(self, now: float) -> bool:
        """Discard the input; send once the line has been silent long enough. False: wait more."""
        line, exchange = self.line, self._exchanges[self._index]
        guard = line.guard
        try:
            data = line.link.take_input()
            if data:
                guard.stray(data, line.clock(), exchange.quarantine)
            elif guard.quiet_at <= now:  # watched since the last look and found empty just now
                guard.found_empty(now)
                self._send(exchange, line.clock())
                return True
            if guard.quiet_at > now >= self._give_up:
                raise line.never_silent(exchange)
        except StarterbusError as exc:
            self._transaction_failed(exc)
            return True
        self.wake_at = min(guard.quiet_at, self._give_up)
        return False

    def _send(self, exchange: Exchange, started: float) -> None:
        line = self.line
        line.guard.sent(started)
        line.requests += 1
        self._deadline = started + exchange.budget
        self._data, self._receiver = b"", None
        self._step = _Step.ANSWER  # before the write: cancelled during it, the line is quarantined
        self.wake_at = self._deadline
        line.link.write(exchange.frame)

    def _in_transaction(self, step: Callable[[Exchange, float], bool], now: float) -> bool:
        """Run an ANSWER or TRAIL step; a bad or missing answer fails the attempt (retried within the policy)."""
        exchange = self._exchanges[self._index]
        try:
            return step(exchange, now)
        except (TimeoutError, DecodeError) as exc:
            try:
                self.line.failed(exchange, exc, self._attempt)
            except StarterbusError as last:
                self._transaction_failed(last)
                return True
            self._step = _Step.START  # the retry waits for the quarantine
            return True
        except StarterbusError as exc:
            self._transaction_failed(exc)
            return True

    def _receive(self, exchange: Exchange, now: float) -> bool:
        """Read what arrived; on a whole answer go on to the trailing silence. False: wait more."""
        line, receiver = self.line, self._receiver
        self.fd = line.link.fd  # watched again after a look-again-later
        if receiver is None:
            chunk = line.link.read_ready(exchange.answer_length - len(self._data))
            if chunk:
                self._at = line.clock()
                self._data += chunk
            data = self._data
            if len(data) == exchange.answer_length:
                response = exchange.quick_decode(data)
                if response is not None:
                    return self._complete(exchange, data, response)
            if len(data) == exchange.answer_length or (
                len(data) >= exchange.header_length and not exchange.good_so_far(data)
            ):
                receiver = self._receiver = ResponseReceiver(exchange.request)
                receiver.feed(data)
            elif chunk and not line.guard.min_char_time and exchange.answer_length - len(data) > 1:
                # the rest of a normal answer cannot be here sooner than the baud rate brings it: look again
                # when all but its last byte can have come, instead of at every byte (only where no wire
                # timing is checked: pty, TCP); the last byte is read as soon as it is there
                self.fd = -1
                rest = (exchange.answer_length - len(data) - 1) * line.char_time
                self.wake_at = min(self._deadline, self._at + rest)
                return False
        else:
            chunk = line.link.read_ready(max(1, receiver.expected_length - len(receiver.received)))
            if chunk:
                self._at = line.clock()
                receiver.feed(chunk)
        if receiver is not None:
            event = receiver.next_event()
            if event is not NEED_DATA:
                if receiver.trailing:  # an exception answer read together with what followed it
                    raise line.guard.trailing(receiver.frame, receiver.trailing)
                return self._complete(exchange, receiver.frame, event)
        if now >= self._deadline:
            if receiver is None:
                receiver = ResponseReceiver(exchange.request)
                receiver.feed(self._data)
            if receiver.received:
                raise receiver.truncated_error()
            raise line.no_answer(exchange)
        self.wake_at = self._deadline
        return False

    def _complete(self, exchange: Exchange, frame: bytes, response: Response) -> bool:
        error = self.line.guard.answer_complete(exchange.frame_length, frame, self._at)
        if error is not None:
            raise error
        self._answer = (frame, response)
        self._step = _Step.TRAIL
        self.wake_at = self.line.guard.trail_until
        return True

    def _trail(self, exchange: Exchange, now: float) -> bool:
        """Bytes after the answer make it suspect; silence until the end of the interval delivers it."""
        line = self.line
        assert self._answer is not None
        frame, response = self._answer
        try:
            extra = line.link.take_input() if self.fd >= 0 else b""
        except TransportError:  # the connection closed after the answer: no byte followed it
            line.mark_broken()
            self.fd = -1  # a closed socket stays readable: the rest of the silence is waited for by time alone
            extra = b""
        if extra:
            raise line.guard.trailing(frame, extra)
        if now < line.guard.trail_until:
            self.wake_at = line.guard.trail_until
            return False
        line.guard.delivered(frame)
        line.count(self._counters, exchange, self._attempt, len(frame), None)
        self._release()
        self._responses.append(response)
        self._index += 1
        self._attempt = 0
        self._step = _Step.START if self._index < len(self._exchanges) else _Step.OVER
        try:
            self._check(exchange, response)
        except StarterbusError as exc:  # an exception answer ends the poll (the line is healthy)
            self._end(exc)
        return True

    def _finish_all(self) -> None:
        try:
            self._outcome = self._finish(self._responses)
        except StarterbusError as exc:
            self._outcome = exc
        self.done = True

    # -- endings ---------------------------------------------------------------------------------------------

    def _transaction_failed(self, exc: StarterbusError) -> None:
        """The current transaction failed for good: count it, then end the task with ``exc``."""
        self.line.given_up(self._counters, self._exchanges[self._index], self._attempt, exc)
        self._end(exc)

    def _end(self, exc: StarterbusError) -> None:
        self._step = _Step.OVER
        self._release()
        self._outcome = exc
        self.done = True

    def _release(self) -> None:
        if self._locked:
            self._locked = False
            self.line.lock.release()
