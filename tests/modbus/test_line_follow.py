"""A blocking RTU transaction while the scheduler's own thread runs the loop (a service) is a ticket of the line's
``RtuJobDriver``, run by that thread: the same frames, answers, errors and counts as the caller's own transaction,
the line's lock shared with the fleet's polls, and nothing left on the loop afterwards."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

import pytest

from starterbus.core.device import open_device
from starterbus.core.errors import StarterbusError
from starterbus.core.media.keeper import Holder
from starterbus.core.scheduler import THREAD_NAME, Scheduler, SchedulerReentryError
from starterbus.core.scheduler import scheduler as process_scheduler
from starterbus.testing.waits import wait_until
from starterbus.tests.modbus.line_task_kit import Poll
from starterbus.tests.modbus.scripted_line import make_line, numbered
from starterbus.transports.modbus.codec.frames import ExceptionResponse, ReadRequest, ReadResponse, WriteRequest
from starterbus.transports.modbus.driver.line import Exchange, RtuLine, TransactionPolicy
from starterbus.transports.modbus.driver.rtu_driver import LOCK_RETRY
from starterbus.transports.modbus.transport.rtu import ModbusRtuTransport

if TYPE_CHECKING:
    from starterbus.tests.modbus.conftest import PtyPeer, SimFactory

GOOD4 = ReadResponse(2, (390, 10, 20, 380)).encode()
URL = "modbus-rtu://{}?unit=2&baudrate=19200&timeout=0.15&retries=1"


@contextmanager
def served() -> Iterator[Scheduler]:
    """The process's scheduler with its own thread running, as under ``serve`` or ``poll``."""
    loop, holder = process_scheduler(), Holder("test_line_follow")
    assert loop.hold(holder) is not None
    try:
        yield loop
    finally:
        loop.unhold(holder)


def line_of(transport: object) -> RtuLine:
    assert isinstance(transport, ModbusRtuTransport)
    line = transport._line
    assert isinstance(line, RtuLine)
    return line


def writers(line: RtuLine) -> list[str]:
    """From now on, the names of the threads that write on the line's link."""
    names: list[str] = []
    link, transfer = line.link, line.link.transfer  # (``write`` is a ``transfer`` without an answer)

    def recording(frame: bytes, size: int, deadline: float, limit: int, wait: float) -> bytes:
        names.append(threading.current_thread().name)
        return transfer(frame, size, deadline, limit, wait)

    link.transfer = recording  # type: ignore[method-assign]
    return names


Outcome = list[object]


def session(
    peer: PtyPeer, actions: Callable[[ModbusRtuTransport], Outcome], writer: str
) -> tuple[Outcome, list[bytes]]:
    with open_device(URL.format(peer.path), "jjr5000") as device:
        transport = device.transport
        assert isinstance(transport, ModbusRtuTransport)
        names = writers(line_of(transport))
        outcome = actions(transport)
    peer.join()
    assert names and set(names) == {writer}
    return outcome, peer.received


def reads(n: int) -> Callable[[ModbusRtuTransport], Outcome]:
    def run(transport: ModbusRtuTransport) -> Outcome:
        seen: Outcome = []
        for _ in range(n):
            try:
                seen.append(transport.read_registers(0x0100, 4))
            except StarterbusError as exc:  # (the port's name differs from one pty to the next)
                seen.append((type(exc), str(exc).replace(line_of(transport).name, "PORT")))
            c = transport.counters()
            seen.append((c.transactions, c.requests, c.retries, c.timeouts, c.errors, c.bytes_sent, c.bytes_received))
        return seen

    return run


REFUSAL = ExceptionResponse(2, 3, 2).encode()
BAD_CRC = GOOD4[:-1] + bytes([GOOD4[-1] ^ 0x01])
SCRIPTS: dict[str, tuple[list[bytes | list[bytes | float] | None], int]] = {
    "good": ([GOOD4, GOOD4], 2),
    "in two pieces": ([[GOOD4[:5], 0.01, GOOD4[5:]]], 1),
    "timeout then good": ([None, GOOD4], 1),
    "refusal": ([REFUSAL], 1),
    "no answer": ([None, None], 1),
    "truncated twice": ([[GOOD4[:9]], [GOOD4[:9]]], 1),
    "bad crc then good": ([BAD_CRC, GOOD4], 1),
}


@pytest.mark.parametrize("name", list(SCRIPTS))
def test_the_loop_sends_receives_and_counts_as_the_caller_does(name: str) -> None:
    from starterbus.tests.modbus.conftest import PtyPeer

    script, n = SCRIPTS[name]
    outcomes = []
    for in_loop in (False, True):
        peer = PtyPeer()
        try:
            peer.serve(script)
            if in_loop:
                with served():
                    outcomes.append(session(peer, reads(n), THREAD_NAME))
            else:
                outcomes.append(session(peer, reads(n), threading.current_thread().name))
        finally:
            peer.close()
    assert outcomes[1] == outcomes[0]
    assert outcomes[0][1], "the script was sent"


def test_the_transaction_runs_in_the_loops_thread_and_leaves_nothing_on_it(make_sim: SimFactory) -> None:
    sim = make_sim("jjr5000")
    params = sim.starters[2].params
    with served() as loop, open_device(sim.url(2), "jjr5000") as device:
        line = line_of(device.transport)
        names = writers(line)
        assert device.read("current_limit")["current_limit"].raw == params["current_limit"]
        device.transport.write_register(0x0103, 380)  # type: ignore[attr-defined]
        assert names == [THREAD_NAME, THREAD_NAME]
        assert line.jobs not in loop.drivers and not line.lock.locked()
        assert line.transactions == 2 and line.requests == 2
    assert sim.starters[2].params["current_limit"] == 380


def test_a_broadcast_is_sent_by_the_loop(peer: PtyPeer) -> None:
    with served(), open_device(f"modbus-rtu://{peer.path}?unit=0&timeout=0.15", "jjr5000") as device:
        line = line_of(device.transport)
        names = writers(line)
        device.transport.write_register(0x0103, 380)  # type: ignore[attr-defined]
        assert names == [THREAD_NAME]
        c = device.transport.counters()
        assert c is not None
        assert (c.transactions, c.requests, c.errors, c.bytes_received) == (1, 1, 0, 0)
    assert peer.read_frame() == WriteRequest(0, 0x0103, 380).encode()


def test_blocking_callers_in_many_threads_share_the_line_through_the_loop(make_sim: SimFactory) -> None:
    sim = make_sim("jjr5000", units=(2, 3))
    sim.starters[3].params["current_limit"] = 250
    errors: list[BaseException] = []
    got: dict[int, list[int]] = {2: [], 3: []}

    def caller(unit: int) -> None:
        try:
            with open_device(sim.url(unit), "jjr5000") as device:
                for _ in range(15):
                    got[unit].append(int(device.read("current_limit")["current_limit"].raw))
        except BaseException as exc:
            errors.append(exc)

    with served():
        threads = [threading.Thread(target=caller, args=(unit,)) for unit in (2, 3, 2, 3)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(30)
    assert not errors
    assert got[2] == [sim.starters[2].params["current_limit"]] * 30 and got[3] == [250] * 30


def test_a_broken_line_is_reopened_by_the_loop(make_sim: SimFactory) -> None:
    sim = make_sim("jjr5000")
    with served(), open_device(sim.url(2), "jjr5000") as device:
        line = line_of(device.transport)
        old = line.link
        line.mark_broken()
        assert device.read("current_limit")["current_limit"].raw == sim.starters[2].params["current_limit"]
        assert line.link is not old and old.closed and not line.broken


def test_a_blocking_call_from_inside_the_loop_is_refused(make_sim: SimFactory) -> None:
    sim = make_sim("jjr5000")
    with served() as loop, open_device(sim.url(2), "jjr5000") as device:
        line = line_of(device.transport)
        exchange = line.prepare(ReadRequest(2, 0x0100, 1), TransactionPolicy(timeout=0.15))
        future = loop.call(lambda now: line.run(exchange))
        with pytest.raises(SchedulerReentryError, match="a blocking call from inside the I/O loop"):
            future.result(10)
        assert device.read("current_limit")["current_limit"].raw == sim.starters[2].params["current_limit"]


def test_a_ticket_outlives_the_loops_thread(peer: PtyPeer) -> None:
    """The loop's thread stops while the answer is on its way: the caller leads and finishes its transaction."""
    answer = threading.Event()

    def device() -> None:
        request = peer.read_frame(timeout=10)
        peer.received.append(request)
        answer.wait(10)
        peer.write(GOOD4)

    responder = threading.Thread(target=device, daemon=True)
    responder.start()
    url = f"modbus-rtu://{peer.path}?unit=2&baudrate=19200&timeout=5&retries=0"
    result: list[object] = []
    with open_device(url, "jjr5000") as opened:
        transport = opened.transport
        assert isinstance(transport, ModbusRtuTransport)
        names = writers(line_of(transport))
        with served():
            caller = threading.Thread(target=lambda: result.append(transport.read_registers(0x0100, 4)))
            caller.start()
            assert wait_until(lambda: bool(peer.received), 10), "the request reached the device"
        answer.set()  # the loop's thread has stopped
        caller.join(10)
        assert result == [(390, 10, 20, 380)] and names == [THREAD_NAME]
        assert not line_of(transport).lock.locked()
    responder.join(5)


def test_a_poll_leaves_the_line_to_the_blocking_callers_waiting_for_it() -> None:
    line, link, clock = make_line(lambda n, frame, at: [(at + 0.01, numbered(n, frame))])
    exchange = Exchange(ReadRequest(2, 0x0100, 1), TransactionPolicy(timeout=0.1), line.char_time)
    (ticket,) = line.jobs.submit((exchange,), clock.now, (None,))  # a caller's ticket, not taken up yet
    try:
        poll = Poll(line)
        poll.task.advance(clock.now)
        assert not link.writes and not line.lock.locked()
        assert poll.task.fd == -1 and poll.task.wake_at == pytest.approx(clock.now + LOCK_RETRY)
    finally:
        line.jobs.withdraw((ticket,), clock.now)
    assert line.jobs not in process_scheduler().drivers
    poll.task.advance(clock.now)
    assert link.writes and line.lock.locked()
    poll.task.cancel()


def test_a_line_without_a_descriptor_stays_with_its_caller(make_sim: SimFactory) -> None:
    sim = make_sim("jjr5000")
    with served(), open_device(sim.url(2) + "&io=pyserial", "jjr5000") as device:
        line = line_of(device.transport)
        assert line.link.fd == -1
        names = writers(line)
        assert device.read("current_limit")["current_limit"].raw == sim.starters[2].params["current_limit"]
        assert names == [threading.current_thread().name]
