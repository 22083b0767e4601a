"""Modbus TCP's MbapEngine through the engine kit: answers go to the transaction with their id, late and repeated
answers (a timed-out id, a retry's first answer) never complete a later one; the gateway's 0x0B is a failed
attempt; and a stream out of step marks the engine broken."""

from __future__ import annotations

from hypothesis import given, settings

from starterbus.core.engine import TicketState
from starterbus.core.errors import TimeoutError, TransportError
from starterbus.testing.engines import EngineKit, Step, schedules
from starterbus.transports.modbus.codec.frames import ReadRequest, ReadResponse, Response
from starterbus.transports.modbus.master.exchange import Exchange, TransactionPolicy
from starterbus.transports.modbus.master.mbap import HEADER, HEADER_LENGTH, MbapEngine, encode_adu

POLICY = TransactionPolicy(timeout=0.1, retries=1, turnaround=0.0, quarantine=0.1)


def read(n: int) -> Exchange:
    return Exchange(ReadRequest(2, n, 1), POLICY, 0.001)


class Gateway:
    """Answers each FC03 read of one register with the register's address as its value; unit 7 with 0x0B."""

    def replies(self, unit: bytes) -> list[bytes]:
        out = []
        while len(unit) >= HEADER_LENGTH:
            transaction, _, length, target = HEADER.unpack_from(unit)
            pdu, unit = unit[HEADER_LENGTH : HEADER_LENGTH - 1 + length], unit[HEADER_LENGTH - 1 + length :]
            answer = b"\x83\x0b" if target == 7 else bytes((3, 2)) + pdu[1:3]
            out.append(encode_adu(transaction, target, answer))
        return out

    def answers(self, request: Exchange, result: Response) -> bool:
        assert isinstance(request.request, ReadRequest)
        return result == ReadResponse(2, (request.request.address,))


KIT = EngineKit(lambda: MbapEngine(outstanding=2, name="gw:502"), read, Gateway(), scale=0.1)


@settings(max_examples=200, deadline=None)
@given(schedules())
def test_the_mbap_engine_keeps_every_rule(schedule: list[Step]) -> None:
    KIT.check(schedule)


def test_a_late_answer_is_stale_and_the_retry_gets_its_own() -> None:
    engine = MbapEngine(name="gw:502")
    ticket = engine.submit(read(5), 0.0)
    (first,) = engine.take_output(0.0)
    engine.advance(0.1)  # timed out: sent again with a new id
    (second,) = engine.take_output(0.1)
    assert first[:2] != second[:2] and ticket.attempts == 2
    late, own = Gateway().replies(first)[0], Gateway().replies(second)[0]
    engine.receive(late, 0.12)
    assert engine.stale == 1 and not engine.take_completed()
    engine.receive(own, 0.13)
    assert engine.take_completed() == [ticket] and ticket.result == ReadResponse(2, (5,))
    assert ticket.received == len(own)


def test_the_gateway_s_0x0b_is_a_failed_attempt_then_a_timeout() -> None:
    engine = MbapEngine(name="gw:502")
    ticket = engine.submit(Exchange(ReadRequest(7, 1, 1), POLICY, 0.001), 0.0)
    for now in (0.0, 0.01):
        (adu,) = engine.take_output(now)
        engine.receive(Gateway().replies(adu)[0], now)
    assert engine.take_completed() == [ticket] and isinstance(ticket.error, TimeoutError)
    assert str(ticket.error) == (
        "gw:502: the device behind the gateway is unreachable: unit 7, exception 0x0B (gateway target device "
        "failed to respond) (attempt 2 of 2)"
    )


def test_a_stream_out_of_step_breaks_the_engine_and_its_loss_fails_what_was_sent() -> None:
    engine = MbapEngine(name="gw:502")
    sent, queued = engine.submit(read(1), 0.0), engine.submit(read(2), 0.0)
    engine.take_output(0.0)
    engine.receive(b"\x00\x01\x00\x07\x00\x03\x02", 0.01)  # protocol id 7
    why = broken(engine)
    assert why is not None and "not an MBAP header" in why
    engine.lost(TransportError(f"gw:502: {why}"), 0.01)
    assert engine.take_completed() == [sent] and sent.state is TicketState.FAILED
    assert broken(engine) is None and queued.state is TicketState.QUEUED and engine.pending == 1


def broken(engine: MbapEngine) -> str | None:
    return engine.broken
