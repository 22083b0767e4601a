"""TicketPoll and run_steps (core/ticket_poll.py) on a fake engine: a poll written as a generator of requests gets
each ticket's result or has its error thrown in, ends with the generator's result, is cancelled with its ticket
withdrawn, gives up at its outer bound when the loop stalls, and waits for its tickets through ``on_progress``
(advanced from the loop), a turn of the scheduler, or a pipe of its own while another thread leads."""

from __future__ import annotations

import select
from collections.abc import Generator, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, cast

import pytest

from starterbus.core import (
    ManualClock,
    PollResult,
    RemoteDeviceError,
    Scheduler,
    StarterbusError,
    Ticket,
    TicketPoll,
    TransportError,
    run_steps,
    run_task,
    wait_ticket,
)
from starterbus.core.engine import FOREVER
from starterbus.core.media import Driver
from starterbus.testing import wait_until


@dataclass(frozen=True)
class Ask:
    name: str
    timeout: float = 1.0


AskTicket = Ticket[Ask, object]


class FakeEngine:
    """Answers a request when it is sent, from ``replies`` (a value, or a StarterbusError it fails with); one with
    no reply stays out until :meth:`reply` or its timeout (never, when the engine ``hangs``)."""

    def __init__(self) -> None:
        self.replies: dict[str, object] = {}
        self.hangs = False
        self.sent: list[str] = []
        self.cancelled: list[str] = []
        self._queue: list[AskTicket] = []
        self._out: list[AskTicket] = []
        self._done: list[AskTicket] = []

    @property
    def deadline(self) -> float:
        if self.hangs or not self._out:
            return FOREVER
        return min(t.sent_at + t.request.timeout for t in self._out if t.sent_at is not None)

    @property
    def pending(self) -> int:
        return len(self._queue) + len(self._out)

    @property
    def broken(self) -> str | None:
        return None

    def submit(self, request: Ask, now: float) -> AskTicket:
        ticket: AskTicket = Ticket(request)
        self._queue.append(ticket)
        return ticket

    def cancel(self, ticket: AskTicket, now: float) -> None:
        for held in (self._queue, self._out):
            if ticket in held:
                held.remove(ticket)
        ticket.cancelled(now)
        self.cancelled.append(ticket.request.name)
        self._done.append(ticket)

    def receive(self, data: object, now: float) -> None:
        pass

    def advance(self, now: float) -> None:
        for ticket in [t for t in self._out if t.sent_at is not None and t.sent_at + t.request.timeout <= now]:
            self._out.remove(ticket)
            ticket.failed(TransportError(f"no answer to {ticket.request.name}"), now)
            self._done.append(ticket)

    def take_output(self, now: float) -> list[str]:
        sent, self._queue = self._queue, []
        for ticket in sent:
            ticket.sent(now)
            self.sent.append(ticket.request.name)
            self._out.append(ticket)
        for ticket in sent:
            if ticket.request.name in self.replies:
                self.reply(ticket.request.name, self.replies[ticket.request.name], now)
        return [t.request.name for t in sent]

    def reply(self, name: str, value: object, now: float) -> None:
        for ticket in [t for t in self._out if t.request.name == name]:
            self._out.remove(ticket)
            if isinstance(value, StarterbusError):
                ticket.failed(value, now)
            else:
                ticket.done(value, now)
            self._done.append(ticket)

    def take_completed(self) -> list[AskTicket]:
        done, self._done = self._done, []
        return done

    def lost(self, error: StarterbusError, now: float) -> None:
        pass

    def refuse(self, error: StarterbusError, now: float) -> None:
        pass


class FakeDriver(Driver[FakeEngine]):
    """No medium: what the engine sends is the test's to see (``engine.sent``)."""

    def __init__(self) -> None:
        super().__init__("fake", FakeEngine)

    def write(self, units: Sequence[Any], now: float) -> None:
        pass


Steps = Generator[Ask, Any, PollResult]


def result_of(*values: object) -> PollResult:
    """A result carrying ``values`` where readings go (the poll's plumbing does not look inside)."""
    return PollResult(None, cast(Any, list(values)))


def values(result: PollResult) -> list[object]:
    return list(result.readings)


def ended(task: TicketPoll[Ask]) -> bool:
    """Whether the poll is done (read through a call: mypy keeps an attribute narrowed across the calls that
    change it)."""
    return task.done


def answer(loop: Scheduler, driver: FakeDriver, name: str, value: object) -> None:
    """Queue the engine's answer to ``name`` for the loop's next turn."""

    def reply(now: float) -> None:
        driver.engine.reply(name, value, now)
        driver.complete(now)

    loop.call(reply)


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock(100.0)


@pytest.fixture
def loop(clock: ManualClock) -> Iterator[Scheduler]:
    sched = Scheduler(clock)
    yield sched
    sched.stop()


@pytest.fixture
def driver(loop: Scheduler) -> FakeDriver:
    made = FakeDriver()
    loop.add(made)
    return made


def advance_to_end(task: TicketPoll[Ask], clock: ManualClock, turns: int = 20) -> None:
    for _ in range(turns):
        task.advance(clock())
        if task.done:
            return
    raise AssertionError("the poll did not end")


def test_each_ticket_result_is_sent_into_the_poll_and_its_return_is_the_result(
    loop: Scheduler, driver: FakeDriver, clock: ManualClock
) -> None:
    driver.engine.replies.update(a=1, b=2)
    got: list[object] = []

    def steps() -> Steps:
        got.append((yield Ask("a")))
        got.append((yield Ask("b")))
        return result_of(*got)

    task = TicketPoll(loop, driver, steps(), where="fake bus")
    advance_to_end(task, clock)
    assert values(task.result()) == [1, 2]
    assert driver.engine.sent == ["a", "b"]  # one ticket at a time, in order
    assert task.fd == -1


def test_a_ticket_error_is_thrown_into_the_poll_which_may_go_on_or_end_with_it(
    loop: Scheduler, driver: FakeDriver, clock: ManualClock
) -> None:
    refused = RemoteDeviceError("fake", 5, "no such object")
    driver.engine.replies.update(a=refused, b=2, c=refused)

    def steps() -> Steps:
        try:
            yield Ask("a")
        except RemoteDeviceError as exc:
            caught = exc
        value = yield Ask("b")
        yield Ask("c")  # not caught: the poll's error
        return result_of(caught, value)

    task = TicketPoll(loop, driver, steps(), where="fake bus")
    advance_to_end(task, clock)
    with pytest.raises(RemoteDeviceError) as raised:
        task.result()
    assert raised.value is refused
    assert driver.engine.sent == ["a", "b", "c"]


def test_cancel_withdraws_the_ticket_under_way_and_closes_the_poll(
    loop: Scheduler, driver: FakeDriver, clock: ManualClock
) -> None:
    closed: list[bool] = []

    def steps() -> Steps:
        try:
            yield Ask("held")
        finally:
            closed.append(True)
        return result_of()

    task = TicketPoll(loop, driver, steps(), where="fake bus")
    task.advance(clock())
    assert driver.engine.sent == ["held"] and not ended(task)
    task.cancel()
    assert ended(task) and closed == [True]
    loop.try_turn()  # the withdrawal is made at the loop's next turn
    assert driver.engine.cancelled == ["held"] and driver.pending == 0
    with pytest.raises(TransportError, match="fake bus: the poll was cancelled"):
        task.result()
    task.cancel()  # idempotent


def test_a_stalled_loop_ends_the_poll_at_its_outer_bound_and_withdraws_the_ticket(
    loop: Scheduler, driver: FakeDriver, clock: ManualClock
) -> None:
    driver.engine.hangs = True  # the engine never ends the ticket, not even at its timeout

    def steps() -> Steps:
        yield Ask("lost", timeout=0.5)
        return result_of()

    task = TicketPoll(loop, driver, steps(), where="fake bus", what="transfer", stall=2.0)
    task.advance(clock())
    assert not ended(task) and task.wake_at == pytest.approx(clock() + 2.5)  # the bound, not the hung deadline
    clock.advance(2.4)
    task.advance(clock())
    assert not ended(task)
    clock.advance(0.1)
    task.advance(clock())
    assert ended(task)
    with pytest.raises(TransportError, match="fake bus: the poll's transfer did not end: the loop stalled"):
        task.result()
    loop.try_turn()
    assert driver.engine.cancelled == ["lost"]


def test_the_engine_timeout_is_thrown_in_before_the_outer_bound(
    loop: Scheduler, driver: FakeDriver, clock: ManualClock
) -> None:
    def steps() -> Steps:
        try:
            yield Ask("late", timeout=0.5)
        except TransportError as exc:
            return result_of(str(exc))
        return result_of("answered")

    task = TicketPoll(loop, driver, steps(), where="fake bus")
    task.advance(clock())
    assert task.wake_at == pytest.approx(clock() + 0.5)  # the driver's deadline: the engine's timeout
    clock.advance(0.5)
    task.advance(clock())
    assert ended(task) and values(task.result()) == ["no answer to late"]


def test_advanced_from_the_loop_the_poll_waits_for_on_progress_and_never_turns_the_loop(
    loop: Scheduler, driver: FakeDriver, clock: ManualClock
) -> None:
    progress: list[int] = []

    def steps() -> Steps:
        first = yield Ask("a")
        second = yield Ask("b")
        return result_of(first, second)

    task = TicketPoll(loop, driver, steps(), where="fake bus", stall=5.0)
    task.on_progress = lambda: progress.append(1)
    task.advance(clock())
    assert (task.fd, task.wake_at) == (-1, clock() + 6.0) and driver.engine.sent == []  # submitted, not turned
    task.advance(clock())  # an early advance adds no second callback
    loop.try_turn()  # the loop (the fleet's) sends it
    assert driver.engine.sent == ["a"] and progress == []
    answer(loop, driver, "a", 1)
    loop.try_turn()
    assert progress == [1]  # the ticket's end told the poller, once
    task.advance(clock())
    loop.try_turn()
    answer(loop, driver, "b", 2)
    loop.try_turn()
    assert progress == [1, 1]
    task.advance(clock())
    assert ended(task) and values(task.result()) == [1, 2]


def test_while_another_thread_leads_the_poll_waits_on_a_pipe_its_ticket_writes_to() -> None:
    loop = Scheduler()
    driver = FakeDriver()
    loop.call(lambda now: loop.add(driver))
    loop.start()
    try:

        def steps() -> Steps:
            value = yield Ask("slow")
            return result_of(value)

        task = TicketPoll(loop, driver, steps(), where="fake bus")
        task.advance(loop.clock())
        assert task.fd >= 0 and not ended(task)  # the loop's own thread leads: no turn here
        assert wait_until(lambda: driver.engine.sent == ["slow"])
        assert select.select([task.fd], [], [], 0)[0] == []
        answer(loop, driver, "slow", 7)
        assert wait_until(lambda: select.select([task.fd], [], [], 0)[0] != [])
        task.advance(loop.clock())
        assert ended(task) and task.fd == -1 and values(task.result()) == [7]
        task._ring(None)  # type: ignore[arg-type]  # a late callback writes to no closed pipe
    finally:
        loop.stop()


def test_run_task_drives_a_ticket_poll_on_a_loop_nobody_leads(
    loop: Scheduler, driver: FakeDriver, clock: ManualClock
) -> None:
    driver.engine.replies.update(a=1)

    def steps() -> Steps:
        return result_of((yield Ask("a")))

    assert values(run_task(TicketPoll(loop, driver, steps(), where="fake bus"), clock)) == [1]


def test_run_steps_waits_for_each_ticket_and_throws_its_error_in(loop: Scheduler, driver: FakeDriver) -> None:
    refused = RemoteDeviceError("fake", 5, "no such object")
    driver.engine.replies.update(a=1, b=refused)
    seen: list[object] = []

    def steps() -> Generator[Ask, Any, list[object]]:
        seen.append((yield Ask("a")))
        try:
            yield Ask("b")
        except RemoteDeviceError as exc:
            seen.append(exc)
        return seen

    assert run_steps(loop, driver, steps(), lambda r: f"fake: {r.name}") == [1, refused]
    assert wait_ticket(loop, driver, Ask("a"), "fake: a").outcome() == 1


def test_wait_ticket_withdraws_a_ticket_past_its_outer_bound() -> None:
    loop = Scheduler()
    driver = FakeDriver()
    loop.add(driver)
    driver.engine.hangs = True
    wrapped: list[Ask] = []

    def wrap(request: Ask) -> Ask:
        wrapped.append(request)
        return request

    with pytest.raises(StarterbusError, match="fake: lost: not done within 0.01 s"):
        wait_ticket(loop, driver, Ask("lost", timeout=0.0), "fake: lost", wrap=wrap, stall=0.01)
    loop.try_turn()
    assert wrapped == [Ask("lost", timeout=0.0)] and driver.engine.cancelled == ["lost"]
