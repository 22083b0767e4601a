"""Modbus RTU's RtuEngine through the engine kit: with no request id, an answer is told from a late or repeated
one by the unit it comes from and by the line's timing rules (LineGuard), and never completes another ticket."""

from __future__ import annotations

from hypothesis import given, settings

from starterbus.core.engine import TicketState
from starterbus.core.errors import TimeoutError
from starterbus.testing.engines import EngineKit, Step, schedules
from starterbus.transports.modbus.codec.crc import append_crc
from starterbus.transports.modbus.codec.frames import ReadRequest, ReadResponse, Response
from starterbus.transports.modbus.master.exchange import Exchange, TransactionPolicy
from starterbus.transports.modbus.master.guard import LineGuard
from starterbus.transports.modbus.master.rtu_engine import RtuEngine

CHAR = 0.001
POLICY = TransactionPolicy(timeout=0.1, retries=1, turnaround=0.0, quarantine=0.1)


def read(n: int) -> Exchange:
    """Request ``n``: one register from unit n + 1 (a late answer to another request is another unit's)."""
    return Exchange(ReadRequest(1 + n % 247, n, 1), POLICY, CHAR)


def engine() -> RtuEngine:
    return RtuEngine(LineGuard(3.5 * CHAR, 0.0, CHAR), "pty-1")


class Slaves:
    """Each unit answers an FC03 read of one register with the register's address."""

    def replies(self, frame: bytes) -> list[bytes]:
        unit, address = frame[0], int.from_bytes(frame[2:4], "big")
        return [append_crc(bytes((unit, 3, 2)) + address.to_bytes(2, "big"))]

    def answers(self, request: Exchange, result: Response | None) -> bool:
        assert isinstance(request.request, ReadRequest)
        return result == ReadResponse(request.request.unit, (request.request.address,))


KIT = EngineKit(engine, read, Slaves(), scale=0.1)


@settings(max_examples=200, deadline=None)
@given(schedules())
def test_the_rtu_engine_keeps_every_rule(schedule: list[Step]) -> None:
    KIT.check(schedule)


def test_an_answer_is_delivered_after_the_trailing_silence_only() -> None:
    rtu = engine()
    ticket = rtu.submit(read(4), 0.0)
    rtu.receive(None, 0.0)
    (frame,) = rtu.take_output(0.0)
    rtu.receive(Slaves().replies(frame)[0], 0.02)
    assert rtu.deadline == 0.02 + 3.5 * CHAR and not rtu.take_completed()
    rtu.advance(rtu.deadline)
    assert rtu.take_completed() == [ticket] and ticket.outcome() == ReadResponse(5, (4,)) and ticket.received == 7


def test_bytes_after_the_answer_fail_the_attempt_and_quarantine_the_line() -> None:
    rtu = engine()
    ticket = rtu.submit(read(4), 0.0)
    rtu.receive(None, 0.0)
    (frame,) = rtu.take_output(0.0)
    answer = Slaves().replies(frame)[0]
    rtu.receive(answer + answer, 0.02)  # a repeat: never delivered
    assert not rtu.take_completed() and rtu.guard.quarantined
    assert rtu.take_output(0.03) == ()  # the retry waits for the quarantine, counted from the failure at 0.02
    rtu.receive(None, 0.11)
    assert rtu.take_output(0.11) == () and rtu.deadline == 0.02 + POLICY.quarantine
    rtu.advance(rtu.deadline)
    rtu.receive(None, rtu.deadline)
    (again,) = rtu.take_output(rtu.deadline)
    assert again == frame and ticket.attempts == 2


def test_no_answer_is_a_timeout_after_the_attempts() -> None:
    rtu = engine()
    ticket = rtu.submit(read(1), 0.0)
    rtu.receive(None, 0.0)
    assert rtu.take_output(0.0)
    rtu.advance(rtu.deadline)  # no answer: the retry waits for the quarantine
    now = rtu.deadline if rtu.take_output(rtu.guard.quiet_at - 0.01) == () else 0.0
    assert now == rtu.guard.quiet_at and not rtu.take_completed()
    rtu.advance(now)
    rtu.receive(None, now)
    assert rtu.take_output(now)
    rtu.advance(rtu.deadline)
    assert rtu.take_completed() == [ticket] and ticket.state is TicketState.FAILED
    assert isinstance(ticket.error, TimeoutError) and "(attempt 2 of 2)" in str(ticket.error)
