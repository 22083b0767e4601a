"""Rule 5 (issue 25, item 7): a slave seen repeating an answer puts the line under the quarantine after answers
too. Transcripts on a fake clock: a scripted link whose bytes arrive at exact times, through the blocking
driver and the poll task; then the guard alone."""

from __future__ import annotations

import itertools

import pytest

from starterbus.core.errors import DecodeError, TimeoutError
from starterbus.tests.modbus.line_task_kit import Poll, values
from starterbus.tests.modbus.scripted_line import SILENCE, Responder, drive, make_line, numbered
from starterbus.transports.modbus.codec.frames import ReadRequest
from starterbus.transports.modbus.master.exchange import TransactionPolicy
from starterbus.transports.modbus.master.guard import CLEAN_ANSWERS, REPEAT_HOLD, LineGuard

POLICY = TransactionPolicy(timeout=0.1, retries=0, quarantine=0.3)
READ = ReadRequest(2, 0x0100, 2)
OTHER = ReadRequest(2, 0x0200, 2)  # another register, an answer of the same length

Arrivals = list[tuple[float, bytes]]


def repeating(script: dict[int, list[float] | None]) -> Responder:
    """Request #n is answered 10 ms after it, then repeated at each time in ``script[n]`` after the request;
    a request whose script is None gets no answer at all."""

    def responder(n: int, frame: bytes, at: float) -> Arrivals:
        if n in script and script[n] is None:
            return []
        again = script.get(n) or []
        answer = numbered(n, frame)
        return [(at + 0.01, answer)] + [(at + t, answer) for t in again]

    return responder


def test_the_first_repeat_of_a_good_answer_can_be_taken_for_a_silent_requests_answer() -> None:
    """The residual itself: nothing was seen repeating before; request #1 gets no answer, and the repeat of
    #0's answer arrives in #1's wait after the wire time, shaped like its answer. Nothing tells them apart."""
    line, _, _ = make_line(repeating({0: [0.05], 1: None}), wire_check=True)
    assert line.transact(READ, POLICY).values == (0, 1)  # type: ignore[union-attr]
    assert line.transact(OTHER, POLICY).values == (0, 1)  # type: ignore[union-attr]  # #0's, not #1's
    assert not line.guard.suspect


def test_a_repeat_seen_after_a_success_quarantines_the_line_after_every_answer() -> None:
    """The same slave, seen repeating once (#0's answer again while the caller was busy): from then on each
    answer is followed by the quarantine, so the repeat of #1's answer is a stray there, and the silent #2 is
    a timeout, not #1's values."""
    line, link, clock = make_line(repeating({0: [0.03], 1: [0.05], 2: None}), wire_check=True)
    assert line.transact(READ, POLICY).values == (0, 1)  # type: ignore[union-attr]
    clock.now += 0.05  # the caller works; the repeat of #0's answer arrives meanwhile
    assert line.transact(OTHER, POLICY).values == (1, 2)  # type: ignore[union-attr]
    assert line.guard.suspect and line.guard.repeats == 1
    with pytest.raises(TimeoutError):
        line.transact(READ, POLICY)
    assert line.guard.repeats == 2  # the repeat of #1's answer, seen in the quarantine after it
    repeat_of_1 = link.writes[1][0] + 0.05
    assert link.writes[2][0] >= repeat_of_1 + REPEAT_HOLD * POLICY.quarantine


def test_the_same_through_a_poll_task() -> None:
    line, link, clock = make_line(repeating({0: [0.03], 1: [0.05], 2: None}), wire_check=True)
    first = Poll(line, READ, policy=POLICY)
    assert values(drive(first.task), first) == [(0, 1)]
    clock.now += 0.05
    second = Poll(line, OTHER, policy=POLICY)
    assert values(drive(second.task), second) == [(1, 2)] and line.guard.suspect
    third = Poll(line, READ, policy=POLICY)
    assert isinstance(drive(third.task), TimeoutError)
    assert link.writes[2][0] >= link.writes[1][0] + 0.05 + REPEAT_HOLD * POLICY.quarantine


def test_an_answer_followed_by_itself_makes_the_line_suspect() -> None:
    line, _, _ = make_line(repeating({0: [0.011]}))  # within the silence after it
    with pytest.raises(DecodeError) as info:
        line.transact(READ, POLICY)
    assert info.value.field == "trailing" and line.guard.suspect


def test_a_delivered_answer_faster_than_the_wire_makes_the_line_suspect() -> None:
    """#0's answer again, complete 2 ms after #1 started: on its way before the request (rule 4), and a repeat."""

    def responder(n: int, frame: bytes, at: float) -> Arrivals:
        if n == 0:
            return [(at + 0.01, numbered(0, frame))]
        return [(at + 0.002, numbered(0, frame)), (at + 0.02, numbered(n, frame))]

    line, _, _ = make_line(responder, wire_check=True)
    assert line.transact(READ, POLICY).values == (0, 1)  # type: ignore[union-attr]
    with pytest.raises(DecodeError) as info:
        line.transact(OTHER, POLICY)
    assert info.value.field == "timing" and line.guard.suspect


def test_a_late_answer_after_a_failure_is_no_repeat() -> None:
    """After a timeout, the late answer is expected (rule 2's quarantine is for it), even with the bytes of an
    answer delivered before (the same register, unchanged): the line is not suspect."""

    def responder(n: int, frame: bytes, at: float) -> Arrivals:
        answer = numbered(0, frame)  # the register does not change
        return [(at + (0.15 if n == 1 else 0.01), answer)]

    line, _, _ = make_line(responder)
    assert line.transact(READ, POLICY).values == (0, 1)  # type: ignore[union-attr]
    with pytest.raises(TimeoutError):
        line.transact(READ, POLICY)
    assert line.transact(READ, POLICY).values == (0, 1)  # type: ignore[union-attr]
    assert line.guard.stray_bytes == 9 and not line.guard.suspect


def test_a_suspect_line_is_healthy_again_after_enough_clean_answers() -> None:
    line, link, clock = make_line(repeating({0: [0.03]}))
    line.transact(READ, POLICY)
    clock.now += 0.05
    line.transact(READ, POLICY)  # the repeat is seen before this request; its answer is the first clean one
    for _ in range(CLEAN_ANSWERS - 1):
        assert line.guard.suspect
        line.transact(READ, POLICY)
    assert not line.guard.suspect
    starts = [at for at, _ in link.writes]
    assert min(b - a for a, b in itertools.pairwise(starts)) >= POLICY.quarantine  # each: a quarantine
    line.transact(READ, POLICY)
    assert link.writes[-1][0] - starts[-1] < POLICY.quarantine  # healthy again: only the silence


# -- the guard alone ---------------------------------------------------------------------------------------------


def delivered_at(guard: LineGuard, at: float, answer: bytes) -> None:
    guard.sent(at - 0.01)
    assert guard.answer_complete(8, answer, at) is None
    guard.delivered(answer)


def test_a_repeat_is_recognised_in_pieces_and_among_other_bytes() -> None:
    answer = numbered(5, READ.encode())
    guard = LineGuard(SILENCE)
    delivered_at(guard, 1.0, answer)
    delivered_at(guard, 1.1, numbered(6, READ.encode()))  # the repeat may be of an earlier answer
    guard.stray(b"\x00" + answer[:4], 1.2, 0.3)
    assert guard.repeats == 0
    guard.stray(answer[4:], 1.201, 0.3)
    assert guard.repeats == 1 and guard.suspect


def test_a_stray_while_suspect_starts_the_clean_count_again() -> None:
    answer = numbered(5, READ.encode())
    guard = LineGuard(SILENCE)
    delivered_at(guard, 1.0, answer)
    guard.stray(answer, 1.2, 0.3)
    now = 2.0
    for _ in range(CLEAN_ANSWERS - 1):
        delivered_at(guard, now, answer)
        assert guard.send_wait(now + SILENCE) == pytest.approx(REPEAT_HOLD * 0.3 - SILENCE)  # from its last byte
        now += 0.5
    guard.stray(b"\xff", now, 0.3)  # noise: the line was not clean
    for _ in range(CLEAN_ANSWERS):
        now += 0.5
        delivered_at(guard, now, answer)
        assert guard.suspect
    delivered_at(guard, now + 0.5, answer)
    assert guard.repeat_hold == 0.0 and guard.send_wait(now + 0.5 + SILENCE) == pytest.approx(0.0)  # healthy


def late_then_own(n: int, frame: bytes, at: float) -> Arrivals:
    """A slave held up once (a loaded simulator): request #0's answer comes after the master's timeout AND its
    quarantine, and every answer after it 60 ms after its request, in order behind it."""
    return [(at + (0.45 if n == 0 else 0.06), numbered(n, frame))]


RETRY = TransactionPolicy(timeout=0.1, retries=1, quarantine=0.3)


def test_a_late_answer_taken_for_the_retrys_is_followed_by_a_quarantine() -> None:
    """Rule 6: #0 times out, its answer arrives after the quarantine and is taken for the retry #1 (the same
    register: its values are right). #1's own answer follows 10 ms later: without rule 6 it was the answer to
    the next read of ANOTHER register (a value shifted by one request, seen once in the conformance suite under
    load); now it is a stray in the quarantine after the first answer, and the next read gets its own."""
    line, link, _ = make_line(late_then_own)
    assert line.transact(READ, RETRY).values == (0, 1)  # type: ignore[union-attr]
    assert line.transact(OTHER, RETRY).values == (2, 3)  # type: ignore[union-attr]
    assert line.guard.stray_bytes == 9
    own_answer_of_1 = link.writes[1][0] + 0.06
    assert link.writes[2][0] >= own_answer_of_1 + RETRY.quarantine


def test_the_same_through_a_poll_task_after_a_retry() -> None:
    line, link, _ = make_line(late_then_own)
    first = Poll(line, READ, policy=RETRY)
    assert values(drive(first.task), first) == [(0, 1)]
    second = Poll(line, OTHER, policy=RETRY)
    assert values(drive(second.task), second) == [(2, 3)]
    assert link.writes[2][0] >= link.writes[1][0] + 0.06 + RETRY.quarantine
