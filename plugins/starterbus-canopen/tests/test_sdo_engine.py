"""SdoEngine, the sans-IO SDO client of one node: the engine kit's rules, the quiet period after a transfer that
ended without its answer (a late response is never a value, whenever it comes within the period), aborts,
refused segmented transfers and TPDO1 kept with its receive time."""

from __future__ import annotations

import heapq
import math

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from starterbus_canopen.codes import Tpdo1
from starterbus_canopen.sdo import (
    ABORT_COMMAND,
    ABORT_TIMEOUT,
    Download,
    SdoEngine,
    SdoRequest,
    SegmentedTransferError,
    Upload,
    abort_frame,
)

from starterbus.core import CanFrame, RemoteDeviceError, TicketState, TimeoutError
from starterbus.testing.engines import EngineKit, Step, schedules

NODE = 5
TIMEOUT = 0.1
ABORTED = 0x2FFF  # objects at or past this index: the peer aborts


def value(index: int, sub: int) -> bytes:
    return (index ^ sub << 8).to_bytes(2, "little")


def answer(command: int, index: int, sub: int, data: bytes = b"") -> CanFrame:
    return CanFrame(0x580 + NODE, bytes((command, index & 0xFF, index >> 8, sub)) + data.ljust(4, b"\0"))


def upload_answer(index: int, sub: int, data: bytes) -> CanFrame:
    return answer(0x43 | (4 - len(data)) << 2, index, sub, data)


class Server:
    """The node, scripted: an upload of ``index:sub`` gives :func:`value`, a download is confirmed, an object at or
    past :data:`ABORTED` is aborted; an abort from the client is not answered."""

    def replies(self, frame: CanFrame) -> list[CanFrame]:
        assert frame.can_id == 0x600 + NODE and len(frame.data) == 8, frame
        command, index, sub = frame.data[0], int.from_bytes(frame.data[1:3], "little"), frame.data[3]
        if command == 0x80:
            return []
        if index >= ABORTED:
            return [answer(0x80, index, sub, (0x06020000).to_bytes(4, "little"))]
        if command == 0x40:
            return [upload_answer(index, sub, value(index, sub))]
        assert command & 0xE3 == 0x23, f"not an expedited download: {frame}"
        return [answer(0x60, index, sub)]

    def answers(self, request: SdoRequest, result: bytes) -> bool:
        if isinstance(request, Download):
            return result == b""
        return result == value(request.index, request.sub)


def request(n: int) -> SdoRequest:
    """Request ``n``: each its own object (a late answer to another carries another index), one in 5 a download,
    one in 7 aborted."""
    index = ABORTED + n if n % 7 == 6 else 0x2000 + n
    if n % 5 == 4:
        return Download(index, n % 3, bytes((n & 0xFF, 1)), TIMEOUT)
    return Upload(index, n % 3, TIMEOUT)


KIT = EngineKit(lambda: SdoEngine(NODE), request, Server(), scale=TIMEOUT)


@settings(max_examples=200, deadline=None)
@given(schedules())
def test_the_sdo_engine_keeps_every_rule(schedule: list[Step]) -> None:
    KIT.check(schedule)


# -- the quiet period: every request reads the same object, the node numbers its answers -----------------------


@settings(max_examples=300, deadline=None)
@example(4, [2 * TIMEOUT - 1e-9], [0.0])  # each answer just before the quiet period ends, the timers on time
@example(4, [TIMEOUT], [TIMEOUT / 2])  # each answer on its deadline, read before the late timer
@given(
    st.integers(1, 8),
    st.lists(st.one_of(st.none(), st.floats(0.0, 2 * TIMEOUT - 1e-9)), min_size=1, max_size=8),
    st.lists(st.floats(0.0, TIMEOUT / 2), min_size=1, max_size=8),
)
def test_a_late_response_is_never_a_value(requests: int, delays: list[float | None], lateness: list[float]) -> None:
    """The k-th request on the wire is answered with k after ``delays[k]`` (None: never), less than two timeouts
    after it was sent (its own timeout, then the quiet period); the engine's timers run late by up to half a
    timeout. All requests read one object, so only the timing tells a late answer from the next one's: a ticket
    that is DONE holds its own number, and every answer not taken is counted as stale."""
    engine = SdoEngine(NODE)
    tickets = [engine.submit(Upload(0x2001, 0, TIMEOUT), 0.0) for _ in range(requests)]
    sent_at: list[float] = []
    pending: list[tuple[float, int]] = []  # (arrives at, number)
    delivered = 0

    def write(now: float) -> None:
        for frame in engine.take_output(now):
            if frame.data[0] == 0x40:
                k = len(sent_at)
                sent_at.append(now)
                delay = delays[k % len(delays)]
                if delay is not None:
                    heapq.heappush(pending, (now + delay, k))

    now = 0.0
    write(now)
    steps = 0
    while not all(t.ended for t in tickets) or pending:
        steps += 1
        assert steps < 1000
        due = engine.deadline + lateness[steps % len(lateness)] if not math.isinf(engine.deadline) else math.inf
        if pending and pending[0][0] <= due:  # what arrived first is read first (before the timer's send)
            now, k = heapq.heappop(pending)
            engine.receive(upload_answer(0x2001, 0, k.to_bytes(2, "little")), now)
            delivered += 1
        else:
            now = due
            engine.advance(now)
        write(now)
    done = [i for i, t in enumerate(tickets) if t.state is TicketState.DONE]
    taken = {int.from_bytes(tickets[i].outcome(), "little") for i in done}
    for i in done:  # ticket i went out as the i-th request (one transfer at a time, in order, no retries)
        assert int.from_bytes(tickets[i].outcome(), "little") == i, (i, sent_at)
    assert engine.stale == delivered - len(taken)
    for ticket in tickets:
        if ticket.state is TicketState.FAILED:
            assert isinstance(ticket.error, TimeoutError)


def test_after_a_timeout_the_node_is_sent_an_abort_then_nothing_for_one_timeout() -> None:
    engine = SdoEngine(NODE, "virtual/x node 5")
    first = engine.submit(Upload(0x2001, 0, 0.3, "read status_word"), 0.0)
    second = engine.submit(Upload(0x2001, 0, 0.3), 0.0)
    (frame,) = engine.take_output(0.0)
    assert frame == CanFrame(0x605, bytes.fromhex("4001200000000000")) and engine.deadline == 0.3
    engine.advance(0.3)
    assert engine.take_output(0.3) == [abort_frame(NODE, 0x2001, 0, ABORT_TIMEOUT)]
    assert engine.take_completed() == [first] and isinstance(first.error, TimeoutError)
    assert str(first.error) == "read status_word: no SDO answer in 0.3 s"
    engine.receive(upload_answer(0x2001, 0, b"\x11\x11"), 0.35)  # the late answer: dropped
    assert engine.stale == 1 and engine.take_output(0.5) == [] and engine.deadline == 0.6
    engine.advance(0.6)
    (again,) = engine.take_output(0.6)
    assert again == frame and second.sent_at == 0.6
    engine.receive(upload_answer(0x2001, 0, b"\x22\x22"), 0.7)
    assert engine.take_completed() == [second] and second.outcome() == b"\x22\x22"


def test_a_transfer_cancelled_after_its_send_quiets_the_node_too() -> None:
    engine = SdoEngine(NODE)
    first = engine.submit(Upload(0x2001, 0, 0.2), 0.0)
    queued = engine.submit(Upload(0x2002, 0, 0.2), 0.0)
    later = engine.submit(Upload(0x2001, 0, 0.2), 0.0)
    assert len(engine.take_output(0.0)) == 1
    engine.cancel(queued, 0.05)  # never sent: nothing on the wire
    engine.cancel(first, 0.1)
    assert engine.take_completed() == [queued, first] and first.state is TicketState.CANCELLED
    assert engine.take_output(0.1) == [] and engine.quiet_until == pytest.approx(0.4)  # its answer's due + 0.2
    engine.receive(upload_answer(0x2001, 0, b"\x01\x00"), 0.3)
    assert engine.stale == 1 and not later.ended
    engine.advance(0.4)
    assert len(engine.take_output(0.4)) == 1 and later.state is TicketState.SENT


def test_an_abort_is_a_remote_device_error_with_its_meaning() -> None:
    engine = SdoEngine(NODE)
    engine.submit(Download(0x2101, 0, b"\x14\x00", what="write ramp_time = 20"), 0.0)
    (frame,) = engine.take_output(0.0)
    assert frame.data == bytes.fromhex("2B01210014000000")
    engine.receive(answer(0x80, 0x2101, 0, (0x08000020).to_bytes(4, "little")), 0.01)
    (done,) = engine.take_completed()
    error = done.error
    assert isinstance(error, RemoteDeviceError) and error.protocol == "CANopen SDO" and error.code == 0x08000020
    assert error.meaning == "data cannot be transferred or stored to the application"
    assert "write ramp_time = 20" in str(error) and engine.quiet_until == -math.inf  # an answer: no quiet period


def test_an_answer_for_another_object_is_not_taken() -> None:
    engine = SdoEngine(NODE)
    ticket = engine.submit(Upload(0x2001, 0), 0.0)
    engine.take_output(0.0)
    engine.receive(upload_answer(0x2002, 0, b"\x05\x00"), 0.01)
    engine.receive(CanFrame(0x585, b"\x4b\x01\x20"), 0.01)  # too short to be an SDO response
    assert not ticket.ended and (engine.stale, engine.malformed) == (1, 1)
    engine.receive(upload_answer(0x2001, 0, b"\x07\x00"), 0.02)
    assert ticket.outcome() == b"\x07\x00"


def test_segmented_transfers_are_refused() -> None:
    engine = SdoEngine(NODE)
    big = engine.submit(Download(0x1008, 0, b"12345"), 0.0)
    assert big.state is TicketState.FAILED and isinstance(big.error, SegmentedTransferError)
    assert engine.take_output(0.0) == []  # nothing on the wire
    name = engine.submit(Upload(0x1008, 0), 0.0)
    engine.take_output(0.0)
    engine.receive(answer(0x41, 0x1008, 0, (12).to_bytes(4, "little")), 0.01)  # "12 bytes follow in segments"
    assert engine.take_output(0.01) == [abort_frame(NODE, 0x1008, 0, ABORT_COMMAND)]
    assert engine.take_completed() == [big, name] and isinstance(name.error, SegmentedTransferError)
    assert "segmented upload of 12 bytes" in str(name.error)


def test_an_unexpected_response_fails_the_transfer_and_quiets_the_node() -> None:
    engine = SdoEngine(NODE)
    ticket = engine.submit(Upload(0x2001, 0, 0.1), 0.0)
    engine.take_output(0.0)
    engine.receive(answer(0x60, 0x2001, 0), 0.02)  # a download's confirmation to an upload
    assert ticket.state is TicketState.FAILED and "unexpected SDO response 585#6001200000000000" in str(ticket.error)
    assert engine.quiet_until == pytest.approx(0.2)


def test_tpdo1_is_kept_with_its_receive_time_and_a_malformed_one_is_dropped() -> None:
    engine = SdoEngine(NODE)
    assert engine.wanted == frozenset({0x585, 0x185}) and SdoEngine(NODE).tpdo is None
    engine.receive(CanFrame(0x185, Tpdo1(0x2000, 1000).encode()), 1.5)
    engine.receive(CanFrame(0x185, b"\x00"), 1.6)
    assert engine.tpdo == (Tpdo1(0x2000, 1000), 1.5) and engine.bad_tpdos == 1
    assert engine.deadline == math.inf and engine.take_output(1.6) == []
