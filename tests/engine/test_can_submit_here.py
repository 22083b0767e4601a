"""``CanDriver.submit_here``: while the loop waits in a virtual bus's own queue, a caller gives its request to the
engine in its own thread (the frame goes out without waking the loop); the loop is woken only when the request's
deadline comes before its wait ends; otherwise (the loop busy, waiting in a ``select``, no one waiting) nothing is
submitted and the caller goes through the loop."""

from __future__ import annotations

import threading
import uuid
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from starterbus.core import TimeoutError
from starterbus.core.engine import Ticket, TicketState
from starterbus.core.media.can import CAN_BUSES, CanDriver
from starterbus.core.media.can_reader import QueueWait
from starterbus.core.media.keeper import keep_running, let_go
from starterbus.core.scheduler import Scheduler
from starterbus.testing import wait_until
from starterbus.tests.engine.test_can_wait import AskEngine, PipeDriver, Responder

WAIT = 10.0


class ThreadEngine(AskEngine):
    """Records the thread each request was submitted in; with ``limit``, a request not answered within it fails."""

    def __init__(self, limit: float | None = None) -> None:
        super().__init__(0x601, 0x581)
        self.limit = limit
        self.threads: list[int] = []
        self._due: dict[Ticket[bytes, bytes], float] = {}

    def submit(self, request: bytes, now: float) -> Ticket[bytes, bytes]:
        self.threads.append(threading.get_ident())
        ticket = super().submit(request, now)
        if self.limit is not None:
            self._due[ticket] = now + self.limit
            self.deadline = min(self._due.values())
        return ticket

    def advance(self, now: float) -> None:
        for ticket, due in list(self._due.items()):
            if now >= due:
                del self._due[ticket]
                if ticket in self._open:
                    self._open.remove(ticket)
                    ticket.failed(TimeoutError("no answer"), now)
                    self._done.append(ticket)
        self.deadline = min(self._due.values(), default=float("inf"))


class Counted:
    """Counts the interrupts of a driver's queue wait."""

    def __init__(self, wait: QueueWait) -> None:
        self.count = 0
        self._interrupt = wait.interrupt
        wait.interrupt = self  # type: ignore[method-assign]

    def __call__(self) -> None:
        self.count += 1
        self._interrupt()


@pytest.fixture
def channel() -> Iterator[str]:
    name = f"can-{uuid.uuid4().hex[:8]}"
    responder = Responder(name)  # answers 0x601 with 0x581, the data plus one
    yield name
    responder.close()
    assert CAN_BUSES.users(("virtual", name)) == 0


def waiting(driver: CanDriver) -> bool:
    """Whether the loop waits in the driver's queue now (its gate free)."""
    assert driver._queue is not None
    if not driver._queue.gate.acquire(blocking=False):
        return False
    driver._queue.gate.release()
    return True


@contextmanager
def waiting_in_queue(loop: Scheduler, channel: str, engine: ThreadEngine) -> Iterator[CanDriver]:
    """``engine`` on the virtual bus ``channel``, the loop's own thread running and waiting in the bus's queue."""
    driver = CanDriver.acquire("virtual", channel, loop)
    try:
        driver.call(lambda now: driver.add(engine), "add")
        keep_running(loop)
        try:
            assert wait_until(lambda: waiting(driver), timeout=WAIT)
            yield driver
        finally:
            let_go(loop)
    finally:
        driver.release()


def test_while_the_loop_waits_the_caller_sends_in_its_own_thread(loop: Scheduler, channel: str) -> None:
    engine = ThreadEngine()
    with waiting_in_queue(loop, channel, engine) as driver:
        assert driver._queue is not None
        interrupts = Counted(driver._queue)  # (from the loop's wait on: starting its thread woke it)
        for n in range(5):
            assert wait_until(lambda: waiting(driver), timeout=WAIT)
            interrupts.count = 0
            handoff = driver.submit_here(engine, bytes((n,)))
            assert handoff is not None
            assert handoff.wait(WAIT)  # ended in the loop's thread, which read the answer
            ticket = handoff.ticket
            assert ticket.state is TicketState.DONE and ticket.result == bytes((n + 1,))
            assert interrupts.count == 0  # the loop was not woken for the request: only by the answer
        assert engine.threads == [threading.get_ident()] * 5


def test_a_request_due_before_the_loops_wait_ends_wakes_it(loop: Scheduler) -> None:
    engine = ThreadEngine(limit=0.05)
    # nobody answers; the loop waits up to its idle second: the request's limit comes first
    with waiting_in_queue(loop, f"can-{uuid.uuid4().hex[:8]}", engine) as driver:
        assert driver._queue is not None
        interrupts = Counted(driver._queue)  # (from the loop's wait on: starting its thread woke it)
        handoff = driver.submit_here(engine, b"\x01")
        assert handoff is not None and interrupts.count == 1
        assert handoff.wait(WAIT)
        ticket = handoff.ticket
        assert ticket.state is TicketState.FAILED and str(ticket.error) == "no answer"


def test_a_request_given_here_is_withdrawn_in_the_loop(loop: Scheduler) -> None:
    engine = ThreadEngine()
    with waiting_in_queue(loop, f"can-{uuid.uuid4().hex[:8]}", engine) as driver:  # nobody answers
        handoff = driver.submit_here(engine, b"\x01")
        assert handoff is not None and not handoff.ended
        given = handoff.ticket
        loop.wait(loop.call(lambda now: driver.withdraw([given], now)), WAIT, "withdraw")
        assert handoff.wait(WAIT) and given.state is TicketState.CANCELLED and driver.pending == 0


def test_a_handoff_followed_through_the_scheduler(loop: Scheduler, channel: str) -> None:
    engine = ThreadEngine()
    with waiting_in_queue(loop, channel, engine) as driver:
        handoff = driver.submit_here(engine, b"\x01")
        assert handoff is not None
        early = handoff.follow()  # (likely before its end: the loop sets it)
        assert loop.wait(early, WAIT, "follow").result == b"\x02"
        late = handoff.follow()  # after its end: set at once
        assert late.done() and late.result() is handoff.ticket


def test_nothing_is_given_here_unless_the_loop_waits_in_the_queue(loop: Scheduler, channel: str) -> None:
    driver = CanDriver.acquire("virtual", channel, loop)
    engine = ThreadEngine()
    other = PipeDriver()
    try:
        driver.call(lambda now: driver.add(engine), "add")
        assert driver.submit_here(engine, b"\x01") is None  # no thread runs the loop: the caller leads instead
        loop.call(lambda now: loop.add(other))
        keep_running(loop)  # now the loop waits in a select (the pipe and the bus's reader)
        try:
            assert wait_until(lambda: not driver.can_block, timeout=WAIT)
            assert driver.submit_here(engine, b"\x02") is None
        finally:
            let_go(loop)
        assert engine.threads == []
        assert not driver.submit_here(ThreadEngine(), b"\x03")  # an engine not on the bus: never here
    finally:
        driver.release()
        loop.call(lambda now: loop.remove(other))
        loop.wait(loop.call(lambda now: None), WAIT, "turn")
        other.close()
    assert driver.submit_here(engine, b"\x04") is None  # closed
