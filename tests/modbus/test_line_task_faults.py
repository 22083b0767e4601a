"""The LineTask against the blocking driver and in the situations only a task meets: cancelled mid-answer,
the line held by another thread, a broken link; on the fake clock of ``scripted_line``."""

from __future__ import annotations

import threading

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from starterbus.core.errors import DecodeError, StarterbusError, TimeoutError, TransportError
from starterbus.core.transport import TransportCounters
from starterbus.tests.modbus.line_task_kit import POLICY, READ, Poll, values
from starterbus.tests.modbus.scripted_line import (
    BAUD,
    SILENCE,
    FakeClock,
    Responder,
    ScriptedLink,
    drive,
    fault_responder,
    make_line,
    numbered,
)
from starterbus.transports.modbus.codec.frames import ExceptionResponse, ReadResponse
from starterbus.transports.modbus.driver.line import RtuLine
from starterbus.transports.modbus.driver.line_task import LOCK_RETRY
from starterbus.transports.modbus.driver.link import SerialSettings


def on_time(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
    return [(at + 0.01, numbered(n, frame))]


# -- the same script through the blocking driver and through the task ------------------------------------------

FAULT = st.tuples(
    st.sampled_from(["ok", "ok", "late", "twice", "trailing", "garbage", "silent", "split", "crc", "exception"]),
    st.floats(0.0, 0.99),
)


def outcome_of(result: object) -> object:
    """Values, or the error's type and text (a RemoteDeviceError is what the transport makes of an exception)."""
    if isinstance(result, ReadResponse):
        return [result.values]
    if isinstance(result, ExceptionResponse):
        return "RemoteDeviceError"
    if isinstance(result, StarterbusError):
        return "RemoteDeviceError" if result.__class__.__name__ == "RemoteDeviceError" else f"{result!r}: {result}"
    return result


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(schedule=st.lists(FAULT, min_size=1, max_size=12), wire_check=st.booleans())
def test_the_task_on_time_does_what_the_blocking_driver_does(
    schedule: list[tuple[str, float]], wire_check: bool
) -> None:
    """Same script: the same results, the same frames at the same times, the same counters."""
    blocking_line, blocking_link, _ = make_line(fault_responder(schedule, POLICY.timeout), wire_check=wire_check)
    task_line, task_link, _ = make_line(fault_responder(schedule, POLICY.timeout), wire_check=wire_check)
    blocking_counters, task_counters = TransportCounters(), TransportCounters()
    exchange = blocking_line.prepare(READ, POLICY)
    for _ in range(12):
        try:
            expected = outcome_of(blocking_line.run(exchange, blocking_counters))
        except (DecodeError, TimeoutError) as exc:
            expected = outcome_of(exc)
        poll = Poll(task_line, counters=task_counters)
        assert outcome_of(values(drive(poll.task), poll)) == expected
    assert [frame for _, frame in task_link.writes] == [frame for _, frame in blocking_link.writes]
    assert [at for at, _ in task_link.writes] == pytest.approx([at for at, _ in blocking_link.writes], abs=1e-9)
    assert task_counters == blocking_counters
    for attr in ("transactions", "requests", "retries"):
        assert getattr(task_line, attr) == getattr(blocking_line, attr), attr
    assert task_line.guard.stray_bytes == blocking_line.guard.stray_bytes


# -- cancelled ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("answered", [False, True])
def test_cancel_while_the_answer_may_still_come_quarantines_the_line_and_gives_it_back(answered: bool) -> None:
    def slow_first(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        return [(at + 0.05, numbered(n, frame))] if n == 0 else on_time(n, frame, at)

    line, link, clock = make_line(slow_first)
    poll = Poll(line)
    poll.task.advance(clock.now)  # the request goes out
    assert len(link.writes) == 1 and line.lock.locked()
    if answered:  # the answer is complete; the task watches the silence after it
        clock.now += 0.05
        poll.task.advance(clock.now)
        assert not poll.task.done and poll.task.wake_at == pytest.approx(clock.now + SILENCE)
    poll.task.cancel()
    cancelled_at = clock.now
    assert poll.task.done and not line.lock.locked()
    with pytest.raises(TransportError, match="poll cancelled"):
        poll.task.result()
    c = poll.counters
    assert (c.transactions, c.requests, c.errors, c.bytes_received) == (1, 1, 1, 0)
    # the next request (a blocking user) waits a quarantine; the late answer seen meanwhile restarts it
    response = line.transact(READ, POLICY)
    assert isinstance(response, ReadResponse) and response.values == (1, 2)
    assert link.writes[1][0] >= max(cancelled_at, link.writes[0][0] + 0.05) + POLICY.quarantine
    poll.task.cancel()  # idempotent
    assert not line.lock.locked()


def test_cancel_while_waiting_for_a_retry_counts_the_requests_sent() -> None:
    line, link, clock = make_line(lambda n, frame, at: [])
    poll = Poll(line)
    poll.task.advance(clock.now)  # the request
    clock.now = poll.task.wake_at
    poll.task.advance(clock.now)  # the timeout: the retry waits for the quarantine
    assert len(link.writes) == 1 and not poll.task.done and line.lock.locked()
    poll.task.cancel()
    c = poll.counters
    assert (c.transactions, c.requests, c.retries, c.errors) == (1, 1, 0, 1)
    assert not line.lock.locked()


def test_a_task_interrupted_while_it_writes_is_cancelled_as_a_request_in_flight() -> None:
    """Interrupted during the write (Ctrl-C in a poller, here a RuntimeError): the request may be on the wire,
    so the poller's cancel() quarantines the line."""
    line, link, clock = make_line(on_time)
    write = link.write

    def interrupted(data: bytes) -> None:
        write(data)
        raise RuntimeError("interrupted")

    link.write = interrupted  # type: ignore[method-assign]
    poll = Poll(line)
    with pytest.raises(RuntimeError):
        poll.task.advance(clock.now)
    assert not line.lock.locked()
    poll.task.cancel()
    assert line.guard.quarantined and line.guard.quiet_at >= clock.now + POLICY.quarantine
    assert (poll.counters.requests, poll.counters.errors) == (1, 1)


def test_cancel_before_the_first_advance_sends_nothing() -> None:
    line, link, _ = make_line(on_time)
    poll = Poll(line)
    poll.task.cancel()
    assert poll.task.done and not link.writes and not line.lock.locked() and not line.guard.quarantined
    assert poll.counters == TransportCounters()


# -- the line held by another thread -------------------------------------------------------------------------


def test_a_line_held_by_another_thread_makes_the_task_wait_then_it_proceeds() -> None:
    line, link, clock = make_line(on_time)
    held, release = threading.Event(), threading.Event()

    def other_user() -> None:
        with line.lock:
            held.set()
            release.wait(10)

    thread = threading.Thread(target=other_user)
    thread.start()
    try:
        assert held.wait(10)
        poll = Poll(line)
        for _ in range(3):
            poll.task.advance(clock.now)
            assert not link.writes and not poll.task.done
            assert poll.task.wake_at == pytest.approx(clock.now + LOCK_RETRY)
            assert poll.task.fd == -1  # another user's answer is not this task's input: do not wake on it
            clock.now = poll.task.wake_at
    finally:
        release.set()
        thread.join(10)
    assert values(drive(poll.task), poll) == [(0, 1)]
    assert poll.task.fd == link.fd and not line.lock.locked()


def test_the_line_is_given_back_between_the_requests_of_a_poll() -> None:
    """A blocking user of the line gets its turn between two requests of a poll (here it takes the line
    while the task checks the first answer, and keeps it for a while)."""
    line, link, clock = make_line(on_time)
    poll = Poll(line, READ, READ)
    taken: list[bool] = []

    def check(exchange: object, response: object) -> None:
        taken.append(line.lock.acquire(blocking=False))

    poll.task._check = check
    while not taken:
        now = clock.now
        poll.task.advance(now)
        clock.now = poll.task.wake_at
    assert taken == [True] and len(link.writes) == 1 and not poll.task.done
    assert poll.task.wake_at == pytest.approx(now + LOCK_RETRY)
    line.lock.release()
    assert values(drive(poll.task), poll) == [(0, 1), (1, 2)]


# -- a broken link ---------------------------------------------------------------------------------------------------


class BrokenLink(ScriptedLink):
    def __init__(self, clock: FakeClock, responder: Responder, broken: str) -> None:
        super().__init__(clock, responder)
        self.broken = broken

    def write(self, data: bytes) -> None:
        super().write(data)
        if self.broken == "write":
            raise TransportError("scripted: write failed: [Errno 5] Input/output error")

    def take_input(self, limit: int = 512) -> bytes:
        if self.broken == "read" and self.writes:
            raise TransportError("scripted: the other end closed the connection")
        return super().take_input(limit)


@pytest.mark.parametrize("broken", ["write", "read"])
def test_a_broken_link_ends_the_task_and_the_next_transaction_reconnects(broken: str) -> None:
    clock = FakeClock()
    links: list[ScriptedLink] = []

    def connect() -> ScriptedLink:
        links.append(BrokenLink(clock, on_time, broken) if not links else ScriptedLink(clock, on_time))
        return links[-1]

    line = RtuLine(connect, SerialSettings(baudrate=BAUD, silence=SILENCE), clock=clock)
    poll = Poll(line)
    outcome = drive(poll.task)
    assert isinstance(outcome, TransportError) and not isinstance(outcome, TimeoutError)
    assert line.broken and not line.lock.locked()
    c = poll.counters
    assert (c.transactions, c.requests, c.errors, c.timeouts) == (1, 1, 1, 0)
    poll = Poll(line)
    assert values(drive(poll.task), poll) == [(0, 1)]
    assert line.usable_link() is links[1] and len(links) == 2 and links[0].closed and poll.task.fd == links[1].fd


class HangUpLink(ScriptedLink):
    """Answers, then the other end closes: every look at the input after the answer says so."""

    def take_input(self, limit: int = 512) -> bytes:
        if self.hung_up():
            raise TransportError("scripted: the other end closed the connection")
        return super().take_input(limit)

    def hung_up(self) -> bool:
        """Closed: a descriptor watched now is readable at once."""
        return bool(self.writes) and not self.buffer and not self.inbox


def test_a_hang_up_after_the_answer_delivers_it_and_waits_out_the_silence_by_time_alone() -> None:
    """A closed socket stays readable: watching it for the rest of the silence would spin the poller."""
    clock = FakeClock()
    link = HangUpLink(clock, on_time)
    line = RtuLine(lambda: link, SerialSettings(baudrate=BAUD, silence=SILENCE), clock=clock)
    poll = Poll(line)
    task, looks = poll.task, []
    while not task.done:
        task.advance(clock.now)
        looks.append((line.broken, task.fd, task.done))
        if task.fd >= 0 and link.hung_up():
            due = clock.now  # the loop's select reports the closed descriptor readable at once
        else:
            due = task.wake_at if task.fd < 0 or link._next() is None else min(task.wake_at, link._next() or 0.0)
        clock.now = max(clock.now, due)
    assert values(task.result(), poll) == [(0, 1)]
    after_hang_up = [fd for broken, fd, done in looks if broken and not done]
    assert after_hang_up and all(fd == -1 for fd in after_hang_up)
    assert line.broken and len(looks) == looks.index((True, -1, False)) + 2  # one more look: at the end
