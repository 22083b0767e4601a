"""The non-blocking LineTask keeps the line's rules on a fake clock: a scripted link whose bytes arrive at exact
times, and a driver that advances the task as a poller would (on time, early, or late), deterministic."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from starterbus.core.errors import DecodeError, RemoteDeviceError, TimeoutError
from starterbus.tests.modbus.line_task_kit import POLICY, READ, Poll, values
from starterbus.tests.modbus.scripted_line import SILENCE, drive, fault_responder, make_line, numbered
from starterbus.transports.modbus.codec.frames import ExceptionResponse, ReadRequest
from starterbus.transports.modbus.master.exchange import TransactionPolicy

ONCE = TransactionPolicy(timeout=0.1, retries=0, quarantine=0.3)


def on_time(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
    return [(at + 0.01, numbered(n, frame))]


# -- before a request ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("step", [0.0005, 0.05])
def test_a_request_never_starts_before_the_quarantine_ends_however_often_the_task_is_advanced(step: float) -> None:
    line, link, clock = make_line(on_time)
    line.guard.failed(clock.now, 0.3)
    quiet_at = line.guard.quiet_at
    poll = Poll(line)
    while not poll.task.done:  # a poller that wakes every ``step`` s, whatever the task asked for
        poll.task.advance(clock.now)
        clock.now += step
    assert values(poll.task.result(), poll) == [(0, 1)]
    assert link.writes[0][0] >= quiet_at


def test_the_next_request_of_a_poll_waits_for_the_silence_after_the_answer() -> None:
    line, link, _ = make_line(on_time)
    poll = Poll(line, READ, ReadRequest(2, 0x0200, 2))
    assert values(drive(poll.task), poll) == [(0, 1), (1, 2)]
    answer_complete = link.writes[0][0] + 0.01
    assert link.writes[1][0] >= answer_complete + SILENCE


@pytest.mark.parametrize("late", [0.0, 0.04])
def test_stray_bytes_while_waiting_restart_the_quarantine(late: float) -> None:
    line, link, clock = make_line(on_time)
    line.guard.failed(clock.now, 0.3)  # quiet at 100.3
    link.inbox.append((clock.now + 0.2, b"\xff\x00"))  # a late answer to an earlier request, say
    poll = Poll(line)
    assert values(drive(poll.task, lambda: late), poll) == [(0, 1)]
    assert link.writes[0][0] >= 100.2 + 0.3  # a full quarantine from the stray bytes, not from the fault
    assert line.guard.stray_bytes == 2


def test_input_found_before_the_first_request_quarantines_the_line() -> None:
    line, link, _ = make_line(on_time)
    link.buffer = b"\x02"  # arrived before the task was made: nobody asked for it
    poll = Poll(line)
    assert values(drive(poll.task), poll) == [(0, 1)]
    assert link.writes[0][0] >= 100.0 + POLICY.quarantine and line.guard.stray_bytes == 1


def test_a_line_that_never_falls_silent_ends_the_task() -> None:
    def noisy(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        return []

    line, link, _ = make_line(noisy)
    link.inbox = [(100.0 + 0.05 * k, b"\x00") for k in range(200)]  # a byte every 50 ms for 10 s
    poll = Poll(line)
    outcome = drive(poll.task)
    assert isinstance(outcome, Exception) and "did not fall silent within 1.2 s" in str(outcome)
    assert not link.writes and not line.lock.locked()


# -- one attempt -------------------------------------------------------------------------------------------------


def test_a_timeout_is_retried_after_the_quarantine_and_the_retry_answers() -> None:
    def second(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        return [] if n == 0 else on_time(n, frame, at)

    line, link, _ = make_line(second)
    poll = Poll(line)
    assert values(drive(poll.task), poll) == [(1, 2)]
    deadline = link.writes[0][0] + poll.exchanges[0].budget
    assert link.writes[1][0] >= deadline + POLICY.quarantine
    c = poll.counters
    assert (c.transactions, c.requests, c.retries, c.timeouts, c.errors) == (1, 2, 1, 0, 0)
    assert (line.transactions, line.requests, line.retries) == (1, 2, 1)


def test_a_timeout_on_the_last_attempt_ends_the_task_naming_the_attempts() -> None:
    line, _, _ = make_line(lambda n, frame, at: [])
    poll = Poll(line)
    outcome = drive(poll.task)
    assert isinstance(outcome, TimeoutError) and str(outcome).endswith("(attempt 2 of 2)")
    assert "no answer from unit 2" in str(outcome)
    c = poll.counters
    assert (c.transactions, c.requests, c.retries, c.timeouts, c.errors) == (1, 2, 1, 1, 1)
    assert line.guard.quarantined and not line.lock.locked()
    with pytest.raises(TimeoutError):
        poll.task.result()


@pytest.mark.parametrize("late", [0.0, 0.01])
def test_bytes_within_the_silence_after_an_answer_drop_it_and_the_retry_answers(late: float) -> None:
    def trailing(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        answer = numbered(n, frame)
        return [(at + 0.01, answer), (at + 0.01 + SILENCE / 2, b"\x00")] if n == 0 else [(at + 0.01, answer)]

    line, link, _ = make_line(trailing)
    poll = Poll(line)
    assert values(drive(poll.task, lambda: late), poll) == [(1, 2)]
    assert link.writes[1][0] - link.writes[0][0] >= POLICY.quarantine

    line, _, _ = make_line(trailing)
    once = Poll(line, policy=ONCE)
    outcome = drive(once.task, lambda: late)
    assert isinstance(outcome, DecodeError) and outcome.field == "trailing", outcome


def test_an_answer_sent_twice_is_never_delivered_even_when_the_task_looks_late() -> None:
    def twice(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        return [(at + 0.01, numbered(n, frame) * 2)]

    line, _, _ = make_line(twice)
    poll = Poll(line, policy=ONCE)
    outcome = drive(poll.task, lambda: 0.05)  # both copies are in the input when the task looks
    assert isinstance(outcome, DecodeError) and outcome.field == "trailing"


@pytest.mark.parametrize("wire_check", [False, True])
def test_a_partial_answer_is_looked_at_again_when_the_rest_can_be_there(wire_check: bool) -> None:
    """Without wire timing (pty, TCP) the task stops watching its input until the whole rest can have come at
    the baud rate; bytes after the answer still make it suspect."""

    def split(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        answer = numbered(n, frame)
        return [(at + 0.01, answer[:3]), (at + 0.0101, answer[3:] + b"\x00")]  # the rest with a byte too many

    line, link, clock = make_line(split, wire_check=wire_check)
    poll = Poll(line, policy=ONCE)
    poll.task.advance(clock.now)
    clock.now = link.writes[0][0] + 0.01
    poll.task.advance(clock.now)  # the first 3 of 9 bytes
    if wire_check:  # the answer's timing is checked: each byte is read when it comes
        deadline = link.writes[0][0] + poll.exchanges[0].budget
        assert poll.task.fd == link.fd and poll.task.wake_at == pytest.approx(deadline)
    else:
        assert poll.task.fd == -1 and poll.task.wake_at == pytest.approx(clock.now + 6 * line.char_time)
    outcome = drive(poll.task)
    assert isinstance(outcome, DecodeError) and outcome.field == "trailing", outcome


def test_a_late_task_reads_an_answer_that_came_after_the_deadline_as_its_own() -> None:
    """Bytes after the request answer it or nobody (the quarantine rules out earlier requests): a task
    advanced late takes what arrived before it decides on a timeout."""

    def late_answer(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        return [(at + 0.15, numbered(n, frame))]  # after the 0.1 s timeout

    line, _, _ = make_line(late_answer)
    poll = Poll(line, policy=ONCE)
    assert values(drive(poll.task, lambda: 0.1), poll) == [(0, 1)]
    on_time_line, _, _ = make_line(late_answer)
    on_time_poll = Poll(on_time_line, policy=ONCE)
    assert isinstance(drive(on_time_poll.task), TimeoutError)


def test_an_exception_answer_ends_the_poll_through_the_check_and_the_line_stays_healthy() -> None:
    def refuse(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        return [(at + 0.01, ExceptionResponse(2, 3, 2).encode())] if n == 0 else on_time(n, frame, at)

    line, link, _ = make_line(refuse)
    poll = Poll(line, READ, ReadRequest(2, 0x0200, 2))
    outcome = drive(poll.task)
    assert isinstance(outcome, RemoteDeviceError) and outcome.code == 2
    assert len(link.writes) == 1  # the poll ended: the second request was not sent
    assert not line.guard.quarantined and not line.lock.locked()
    c = poll.counters
    assert (c.transactions, c.requests, c.errors, c.bytes_received) == (1, 1, 0, 5)


def test_an_exception_answer_read_together_with_bytes_after_it_is_suspect_not_a_refusal() -> None:
    def refuse_and_more(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        return [(at + 0.01, ExceptionResponse(2, 3, 2).encode() + b"\x00\x01")]

    line, _, _ = make_line(refuse_and_more)
    poll = Poll(line, policy=ONCE)
    outcome = drive(poll.task)
    assert isinstance(outcome, DecodeError) and outcome.field == "trailing", outcome
    assert line.guard.quarantined


@pytest.mark.parametrize("cut", [3, 5, 8])
def test_a_truncated_answer_is_an_error_naming_what_arrived(cut: int) -> None:
    line, _, _ = make_line(lambda n, frame, at: [(at + 0.01, numbered(n, frame)[:cut])])
    poll = Poll(line, policy=ONCE)
    outcome = drive(poll.task)
    assert isinstance(outcome, DecodeError) and outcome.field == "length"
    assert f"truncated answer: {cut} of 9 bytes arrived" in str(outcome)


def test_an_answer_faster_than_the_wire_is_refused_on_a_real_serial_setting() -> None:
    def early(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        return [(at + (0.001 if n == 0 else 0.02), numbered(n, frame))]  # 8 + 9 characters take 8.9 ms

    line, _, _ = make_line(early, wire_check=True)
    poll = Poll(line, policy=ONCE)
    outcome = drive(poll.task)
    assert isinstance(outcome, DecodeError) and outcome.field == "timing"
    assert "sooner than request and answer take on the wire" in str(outcome)
    poll = Poll(line, policy=ONCE)
    assert values(drive(poll.task), poll) == [(1, 2)]
    # without the wire rule (a pty, TCP) the same early answer is taken
    line, _, _ = make_line(early, wire_check=False)
    poll = Poll(line, policy=ONCE)
    assert values(drive(poll.task), poll) == [(0, 1)]


# -- random fault schedules, the task advanced late by random amounts -----------------------------------------

STEP = st.tuples(
    st.sampled_from(["ok", "ok", "late", "twice", "trailing", "garbage", "silent", "split", "exception"]),
    st.floats(0.0, 0.99),
)


@settings(max_examples=150, deadline=None, derandomize=True, database=None)
@given(schedule=st.lists(STEP, min_size=1, max_size=20), lateness=st.lists(st.floats(0.0, 0.2), min_size=1))
def test_random_fault_schedules_never_give_a_task_a_foreign_value(
    schedule: list[tuple[str, float]], lateness: list[float]
) -> None:
    """Late answers up to the very end of the quarantine, trailing bytes up to the end of the silence, a task
    advanced up to 0.2 s (twice the timeout) after it asked: every value answers the last request sent."""
    policy = TransactionPolicy(timeout=0.1, retries=1, quarantine=0.3)

    line, link, _ = make_line(fault_responder(schedule, policy.timeout))
    delays = iter(lateness * 1000)
    delivered = 0
    for _ in range(20):
        poll = Poll(line, policy=policy)
        outcome = drive(poll.task, lambda: next(delays))
        if isinstance(outcome, Exception):
            assert isinstance(outcome, DecodeError | TimeoutError | RemoteDeviceError), outcome
            continue
        last = len(link.writes) - 1
        assert values(outcome, poll) == [(last, last + 1)]
        delivered += 1
    if any(fault in ("ok", "split") for fault, _ in schedule) and max(lateness) == 0:
        assert delivered
