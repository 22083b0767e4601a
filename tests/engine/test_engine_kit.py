"""The engine kit (starterbus.testing.engines) on the toy engine, and on broken ones it must catch."""

from __future__ import annotations

import pytest
from hypothesis import given, settings

from starterbus.core.engine import Ticket, TicketState, TicketStateError
from starterbus.core.errors import TimeoutError
from starterbus.testing.engines import EngineKit, Step, schedules
from starterbus.tests.engine.toy import ToyEngine, ToyPeer, request

KIT = EngineKit(lambda: ToyEngine(timeout=0.1, attempts=2, outstanding=2), request, ToyPeer(), scale=0.1)


@settings(max_examples=200, deadline=None)
@given(schedules())
def test_the_toy_engine_keeps_every_rule(schedule: list[Step]) -> None:
    KIT.check(schedule)


def test_a_late_reply_is_counted_not_delivered() -> None:
    engine = ToyEngine(timeout=0.1, attempts=1)
    first = engine.submit(b"a", 0.0)
    (sent,) = engine.take_output(0.0)
    engine.advance(0.1)
    second = engine.submit(b"b", 0.1)
    engine.take_output(0.1)
    engine.receive(ToyPeer().replies(sent)[0], 0.15)  # the first one's answer, late
    assert engine.take_completed() == [first] and first.state is TicketState.FAILED
    assert engine.stale == 1 and second.state is TicketState.SENT


class FirstComeEngine(ToyEngine):
    """Wrong: an answer goes to the oldest ticket sent, whatever its id (a late reply becomes a value)."""

    def receive(self, data: bytes | None, now: float) -> None:
        if data and self._sent:
            ticket, _ = self._sent.pop(min(self._sent))
            ticket.done(data[2:], now)
            self._done.append(ticket)


def test_the_kit_catches_a_late_reply_taken_for_another_ticket() -> None:
    kit = EngineKit(FirstComeEngine, request, ToyPeer(), scale=0.1)
    late = [Step("submit"), Step("deadline"), Step("deadline"), Step("submit"), Step("deliver", 0)]
    with pytest.raises(AssertionError, match="does not answer it"):
        kit.run(late)


class StuckEngine(ToyEngine):
    """Wrong: a timed-out ticket is never retired, its deadline stays where it was."""

    def advance(self, now: float) -> None:
        pass


def test_the_kit_catches_a_deadline_that_does_not_move() -> None:
    kit = EngineKit(StuckEngine, request, ToyPeer(), scale=0.1)
    with pytest.raises(AssertionError, match="busy loop"):
        kit.run([Step("submit"), Step("deadline")])


class TwiceEngine(ToyEngine):
    """Wrong: a completed ticket is reported again."""

    def take_completed(self) -> list[Ticket[bytes, bytes]]:
        done = super().take_completed()
        return done + done


def test_the_kit_catches_a_ticket_completed_twice() -> None:
    kit = EngineKit(TwiceEngine, request, ToyPeer(), scale=0.1)
    with pytest.raises(AssertionError, match="completed twice"):
        kit.run([Step("submit"), Step("deliver")])


class ForgetfulEngine(ToyEngine):
    """Wrong: a cancelled ticket that was sent is dropped without an end."""

    def cancel(self, ticket: Ticket[bytes, bytes], now: float) -> None:
        for ident, (sent, _) in list(self._sent.items()):
            if sent is ticket:
                del self._sent[ident]


def test_the_kit_catches_a_ticket_that_never_ends() -> None:
    kit = EngineKit(ForgetfulEngine, request, ToyPeer(), scale=0.1)
    with pytest.raises(AssertionError, match="never ended"):
        kit.run([Step("submit"), Step("cancel")])


class MoodyEngine(ToyEngine):
    """Wrong: the output depends on something outside its inputs (not replayable)."""

    runs = 0

    def __init__(self) -> None:
        super().__init__()
        MoodyEngine.runs += 1
        self._next = MoodyEngine.runs


def test_the_kit_catches_an_engine_that_does_not_replay() -> None:
    kit = EngineKit(MoodyEngine, request, ToyPeer(), scale=0.1)
    with pytest.raises(AssertionError, match="replayed"):
        kit.check([Step("submit")])


def test_a_ticket_ends_once() -> None:
    ticket: Ticket[str, int] = Ticket("read")
    ticket.sent(1.0)
    ticket.sent(2.0)
    assert (ticket.state, ticket.attempts, ticket.sent_at) == (TicketState.SENT, 2, 1.0)
    ticket.done(7, 3.0)
    assert ticket.outcome() == 7 and ticket.done_at == 3.0
    with pytest.raises(TicketStateError, match="ended twice: done, then failed"):
        ticket.failed(TimeoutError("late"), 4.0)
    with pytest.raises(TicketStateError, match="sent after it ended"):
        ticket.sent(5.0)
    assert ticket.result == 7 and ticket.error is None


def test_a_failed_ticket_raises_its_error_and_a_cancelled_one_has_no_result() -> None:
    failed: Ticket[str, int] = Ticket("read")
    failed.failed(TimeoutError("no answer"), 1.0)
    with pytest.raises(TimeoutError, match="no answer"):
        failed.outcome()
    cancelled: Ticket[str, int] = Ticket("read")
    cancelled.cancelled(1.0)
    with pytest.raises(TicketStateError, match="no result: cancelled"):
        cancelled.outcome()
