"""The line's timing rules on a fake clock: the sans-IO LineGuard alone, then the real RtuLine driver replaying
transcripts against a scripted link whose bytes arrive at exact times (no pty, no sleeping, deterministic)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from starterbus.core.errors import DecodeError, TimeoutError
from starterbus.tests.modbus.scripted_line import SILENCE, fault_responder, make_line, numbered
from starterbus.transports.modbus.codec.frames import ReadRequest, ReadResponse
from starterbus.transports.modbus.driver.link import SerialSettings
from starterbus.transports.modbus.master.exchange import TransactionPolicy
from starterbus.transports.modbus.master.guard import LineGuard

# -- the guard alone ---------------------------------------------------------------------------------------------


def test_a_fault_quarantines_and_stray_bytes_restart_it() -> None:
    guard = LineGuard(SILENCE)
    guard.failed(10.0, 0.3)
    assert guard.quarantined and guard.send_wait(10.0) == pytest.approx(0.3)
    guard.stray(b"\x02\x03", 10.2, 0.1)  # the longer quarantine in force counts, from the stray bytes
    assert guard.send_wait(10.2) == pytest.approx(0.3) and guard.stray_bytes == 2
    assert guard.send_wait(10.5) == pytest.approx(0.0)


def test_the_first_answer_after_a_failure_is_quarantined_then_the_line_is_healthy() -> None:
    """Rule 6: a late answer to the failed request may still follow the first answer delivered after it."""
    guard = LineGuard(SILENCE)
    guard.failed(1.0, 0.5)
    guard.sent(1.6)
    assert guard.answer_complete(8, b"x" * 7, 1.61) is None
    assert guard.trail_until == pytest.approx(1.61 + SILENCE)
    guard.delivered(b"x" * 7)
    assert guard.hold == 0.5 and guard.send_wait(1.61) == pytest.approx(0.5)
    guard.sent(2.2)
    assert guard.answer_complete(8, b"y" * 7, 2.21) is None
    guard.delivered(b"y" * 7)
    assert not guard.quarantined and guard.send_wait(2.21 + SILENCE) == pytest.approx(0.0)
    guard.stray(b"\x00", 3.0, 0.2)  # noise on a healthy line: quarantined again
    assert guard.hold == 0.2 and guard.send_wait(3.0) == pytest.approx(0.2)


def test_stray_bytes_before_a_request_quarantine_the_answer_after_it() -> None:
    guard = LineGuard(SILENCE)
    guard.stray(b"\x00", 1.0, 0.2)
    guard.sent(1.3)
    assert guard.answer_complete(8, b"x" * 7, 1.31) is None
    guard.delivered(b"x" * 7)
    assert guard.send_wait(1.31) == pytest.approx(0.2)


def test_an_answer_faster_than_the_wire_is_refused() -> None:
    settings_ = SerialSettings(baudrate=9600, parity="E", stopbits=1)  # 11 bits a character
    guard = LineGuard(SILENCE, settings_.min_char_time)
    guard.sent(5.0)
    answer = ReadResponse(2, (1,)).encode()  # 8 + 7 characters: 17.2 ms at 9600 baud, 11 bits
    error = guard.answer_complete(8, answer, 5.010)
    assert isinstance(error, DecodeError) and error.field == "timing" and error.data == answer
    assert guard.answer_complete(8, answer, 5.0165) is None  # within the 5 % tolerance
    assert LineGuard(SILENCE).answer_complete(8, answer, 5.0) is None  # no wire rule on a pty or TCP


def test_trailing_bytes_name_the_answer_and_what_followed() -> None:
    error = LineGuard(SILENCE).trailing(b"\x02\x03", b"\xff")
    assert error.field == "trailing" and error.data == b"\x02\x03\xff" and "FF" in str(error)


# -- the driver on a fake clock ----------------------------------------------------------------------------------


POLICY = TransactionPolicy(timeout=0.1, retries=0, quarantine=0.3)
READ = ReadRequest(2, 0x0100, 2)


def test_replay_a_late_answer_restarts_the_quarantine() -> None:
    def responder(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        return [(at + 0.25, numbered(n, frame))] if n == 0 else [(at + 0.01, numbered(n, frame))]

    line, link, _ = make_line(responder)
    with pytest.raises(TimeoutError):
        line.transact(READ, POLICY)
    assert line.transact(READ, POLICY).values == (1, 2)  # type: ignore[union-attr]
    late_at = link.writes[0][0] + 0.25
    assert link.writes[1][0] >= late_at + 0.3  # a full quarantine after the late answer's bytes
    assert line.guard.stray_bytes == 9


def test_replay_trailing_bytes_within_the_silence_make_the_answer_suspect() -> None:
    def responder(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        answer = numbered(n, frame)
        return [(at + 0.01, answer), (at + 0.01 + SILENCE / 2, b"\x00")] if n == 0 else [(at + 0.01, answer)]

    line, link, _ = make_line(responder)
    with pytest.raises(DecodeError) as info:
        line.transact(READ, POLICY)
    assert info.value.field == "trailing"
    assert line.transact(READ, POLICY).values == (1, 2)  # type: ignore[union-attr]
    assert link.writes[1][0] - link.writes[0][0] >= 0.3


def test_replay_a_byte_after_the_silence_quarantines_before_the_next_send() -> None:
    """The answer was followed by silence, so it is delivered; the byte found when input is discarded before
    the next request quarantines the line."""

    def responder(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        answer = numbered(n, frame)
        return [(at + 0.01, answer), (at + 0.05, b"\xff")] if n == 0 else [(at + 0.01, answer)]

    line, link, clock = make_line(responder)
    assert line.transact(READ, POLICY).values == (0, 1)  # type: ignore[union-attr]
    clock.now += 0.1  # the caller works a while; the stray byte arrives meanwhile
    assert line.transact(READ, POLICY).values == (1, 2)  # type: ignore[union-attr]
    # found (at the earliest) when the caller came back 0.1 s later: a full quarantine from then
    assert link.writes[1][0] - link.writes[0][0] >= 0.1 + 0.3 and line.guard.stray_bytes == 1


def test_replay_an_answer_faster_than_the_wire_is_refused() -> None:
    def responder(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        return [(at + (0.001 if n == 0 else 0.02), numbered(n, frame))]  # 8 + 9 characters take 8.9 ms

    line, _, _ = make_line(responder, wire_check=True)
    with pytest.raises(DecodeError, match="sooner than request and answer take on the wire"):
        line.transact(READ, POLICY)
    assert line.transact(READ, POLICY).values == (1, 2)  # type: ignore[union-attr]


STEP = st.tuples(
    st.sampled_from(["ok", "ok", "late", "twice", "trailing", "garbage", "silent", "split"]), st.floats(0.0, 0.99)
)


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(schedule=st.lists(STEP, min_size=1, max_size=30))
def test_replay_random_fault_schedules_never_return_a_foreign_value(schedule: list[tuple[str, float]]) -> None:
    """Exact times: late answers up to the very end of the quarantine, trailing bytes up to the end of the
    silence; 300 schedules x 30 reads."""
    policy = TransactionPolicy(timeout=0.1, retries=1, quarantine=0.3)

    line, link, _ = make_line(fault_responder(schedule, policy.timeout))
    values = 0
    for _ in range(30):
        try:
            response = line.transact(READ, policy)
        except (DecodeError, TimeoutError):
            continue
        last = len(link.writes) - 1
        assert response.values == (last, last + 1)  # type: ignore[union-attr]
        values += 1
    if any(fault in ("ok", "split") for fault, _ in schedule):
        assert values


def test_send_now_only_right_after_a_silence_that_was_watched() -> None:
    guard = LineGuard(SILENCE, fresh=0.0005)
    assert not guard.send_now(1.0)  # nothing watched yet: the driver discards the input first
    guard.sent(1.0)
    assert guard.answer_complete(8, b"x" * 7, 1.01) is None
    guard.delivered(b"x" * 7)
    assert not guard.send_now(1.01 + SILENCE / 2)  # the silence is not over
    assert guard.send_now(1.01 + SILENCE + 0.0004) and guard.started == 1.01 + SILENCE + 0.0004
    assert not guard.send_now(1.01 + SILENCE + 0.001)  # watched too long ago: discard first
