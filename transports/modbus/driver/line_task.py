"""A poll's transactions on one RTU line as a :class:`~starterbus.core.polling.PollTask`: the
:class:`~starterbus.transports.modbus.master.rtu_engine.RtuEngine` on the line's descriptor (:class:`RtuDriver`, a
:class:`~starterbus.core.media.StreamDriver`), for the fleet's multiplexer (``fleet/mux.py``) until the fleet
runs on the scheduler (docs/engine.md, step 4).

The rules are the engine's, that is the :class:`~starterbus.transports.modbus.master.guard.LineGuard`'s, which the
blocking :meth:`RtuLine.run <starterbus.transports.modbus.driver.line.RtuLine.run>` shares: one guard per line. The
line's lock is held from a request's start to its answer's delivery, so blocking users of the same line in this
process wait their turn (and the task looks again after :data:`LOCK_RETRY` while one holds it, or while their
tickets wait for the line: :class:`~starterbus.transports.modbus.driver.rtu_driver.RtuJobDriver`).

Times: the driver reads the line's clock just before a write (the request counts as started then), and just
after a read (an answer is complete then). It looks at the input before every step, so a task advanced late
reads what arrived meanwhile before the engine decides on a timeout, and the silence before a request is
checked on input found empty just before it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import cast

from starterbus.core import PollResult, PollTask, StarterbusError, TicketState, TransportCounters, TransportError
from starterbus.transports.modbus.codec.messages import Response
from starterbus.transports.modbus.driver.line import RtuLine
from starterbus.transports.modbus.driver.rtu_driver import CONNECT_LOOK, LOCK_RETRY, RtuDriver
from starterbus.transports.modbus.master.exchange import Exchange
from starterbus.transports.modbus.master.rtu_engine import ANSWER, RtuTicket

# (an Enum class's attributes are slow to read)
_QUEUED, _SENT, _DONE, _FAILED = TicketState.QUEUED, TicketState.SENT, TicketState.DONE, TicketState.FAILED
_ANSWER = ANSWER
_LEADS = (None,)  # a ticket's future: none, the task watches the ticket itself

__all__ = ["LOCK_RETRY", "LineTask", "RtuDriver"]


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
        for exchange in exchanges:
            if exchange.broadcast:
                raise ValueError("a broadcast gets no answer: it is not a poll")
        self.line = line
        self._exchanges = exchanges
        self._counters = counters
        self._check = check
        self._finish = finish
        self._driver = line.polls
        self._responses: list[Response] = []
        self._ticket: RtuTicket | None = None
        self._locked = False
        self._outcome: PollResult | StarterbusError | None = None
        self.fd = -1  # nothing to watch before the line is taken (and reopened if it broke)
        self.wake_at = 0.0
        self.done = False
        if not exchanges:
            self._finish_all()

    # -- the PollTask interface ------------------------------------------------------------------------------

    def advance(self, now: float) -> None:
        if self.done:
            return
        driver, line = self._driver, self.line
        try:
            while True:
                ticket = self._ticket
                if ticket is None:
                    if not self._locked:
                        # (blocking callers' transactions waiting for the line go first: see RtuJobDriver)
                        if line.jobs.waiting or not line.lock.acquire(blocking=False):
                            self.fd = -1  # the line's input is its holder's until it is free: look again soon
                            self.wake_at = now + LOCK_RETRY
                            return
                        self._locked = True
                    if line.broken and not line.reopen():
                        self.fd = -1  # a connection being made, without blocking the loop: looked at again soon
                        self.wake_at = now + CONNECT_LOOK
                        return
                    line.transactions += 1
                    (submitted,) = driver.submit((self._exchanges[len(self._responses)],), now, _LEADS)
                    ticket = self._ticket = cast(RtuTicket, submitted)
                driver.step(now, True)
                state = ticket.state
                if state is _SENT or state is _QUEUED:
                    self._watch(driver)
                    return
                if self._ended(ticket):
                    return
        except StarterbusError as exc:
            self._failed(exc)
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
        ticket = self._ticket
        if ticket is not None and not ticket.ended:
            self._driver.withdraw((ticket,), self.line.clock())
            self._counted(ticket)
        self._ticket = None
        self._release()
        if not self.done:
            self._outcome = TransportError(f"{self.line.name}: poll cancelled")
            self.done = True

    # -- the steps -------------------------------------------------------------------------------------------

    def _watch(self, driver: RtuDriver) -> None:
        line, engine = self.line, driver.engine
        self.fd, self.wake_at = -1 if line.broken else line.link.fd, engine.deadline
        if engine.phase is _ANSWER and not line.guard.min_char_time:
            # the rest of a normal answer cannot be here sooner than the baud rate brings it: look again when
            # all of it can have come, instead of at every byte (only where no wire timing is checked: pty,
            # TCP). ``at`` is after the first bytes arrived, so the rest is usually all there then (one wake
            # for it, not two); what is not is waited for on the descriptor
            got, at = engine.answer_so_far
            exchange = engine.answering
            if got > 0 and exchange is not None and exchange.answer_length > got:
                rest = at + (exchange.answer_length - got) * line.char_time
                if rest > driver.at:
                    self.fd = -1
                    self.wake_at = min(self.wake_at, rest)

    def _ended(self, ticket: RtuTicket) -> bool:
        """The transaction of ``ticket`` ended; whether the task is done."""
        self._ticket = None
        self._release()
        self._counted(ticket)
        if ticket.state is not _DONE:
            assert ticket.error is not None
            self._end(ticket.error)
            return True
        response = ticket.result
        assert response is not None  # a poll has no broadcast
        self._responses.append(response)
        try:
            self._check(ticket.request, response)
        except StarterbusError as exc:  # an exception answer ends the poll (the line is healthy)
            self._end(exc)
            return True
        if len(self._responses) == len(self._exchanges):
            self._finish_all()
        return self.done

    def _counted(self, ticket: RtuTicket) -> None:
        """What the ended (or cancelled) transaction put on the wire, into the counters; a transport error
        breaks the line (reopened before the next transaction)."""
        line = self.line
        line.count_ticket(self._counters, ticket)
        if ticket.state is _FAILED:
            assert ticket.error is not None
            line.broke(ticket.error)

    def _finish_all(self) -> None:
        try:
            self._outcome = self._finish(self._responses)
        except StarterbusError as exc:
            self._outcome = exc
        self.done = True

    # -- endings ---------------------------------------------------------------------------------------------

    def _failed(self, exc: StarterbusError) -> None:
        """The line failed under the current transaction (a read or write of its link): it ends with ``exc``."""
        ticket = self._ticket
        if ticket is not None and not ticket.ended:
            self._driver.crash(exc, self.line.clock())
            self._counted(ticket)
        elif ticket is None and not self.done:
            self.line.given_up(self._counters, self._exchanges[len(self._responses)], 1, exc)
        self._ticket = None
        self._end(exc)

    def _end(self, exc: StarterbusError) -> None:
        self._release()
        self._outcome = exc
        self.done = True

    def _release(self) -> None:
        if self._locked:
            self._locked = False
            self.line.lock.release()
