"""The CAN driver over python-can's virtual bus (no descriptor: the loop waits on the bus's own queue, or, when it
waits on other descriptors too, one reader thread and a wake pipe): requests led by the caller, frames routed by
identifier to the engines that want them, one wake-up per burst of the reader, an engine that raises contained,
periodic outputs at the driver's deadlines, one driver per (interface, channel)."""

from __future__ import annotations

import os
import threading
import uuid
from collections.abc import Iterator, Sequence
from typing import Any

import can
import pytest

from starterbus.core import CanFrame, TimeoutError
from starterbus.core.engine import FOREVER, Ticket, TicketState
from starterbus.core.media.can import CAN_BUSES, CanDriver, ToEngine
from starterbus.core.media.keeper import keep_running, let_go
from starterbus.core.scheduler import Scheduler
from starterbus.testing import wait_until


class AskEngine:
    """Sends ``CanFrame(ask, data)`` per request; the ticket ends with the data of the next frame ``answer``, or
    fails after ``timeout``."""

    def __init__(self, ask: int, answer: int, timeout: float = 1.0) -> None:
        self.ask, self.answer, self.timeout = ask, answer, timeout
        self.wanted = frozenset({answer})
        self._queue: list[Ticket[bytes, bytes]] = []
        self._out: list[CanFrame] = []
        self._done: list[Ticket[bytes, bytes]] = []
        self._until = FOREVER
        self.seen: list[CanFrame] = []
        self.broken = False

    @property
    def deadline(self) -> float:
        return self._until

    def submit(self, request: bytes, now: float) -> Ticket[bytes, bytes]:
        ticket: Ticket[bytes, bytes] = Ticket(request)
        self._queue.append(ticket)
        if len(self._queue) == 1:
            self._send(ticket, now)
        return ticket

    def _send(self, ticket: Ticket[bytes, bytes], now: float) -> None:
        ticket.sent(now)
        self._out.append(CanFrame(self.ask, ticket.request))
        self._until = now + self.timeout

    def cancel(self, ticket: Ticket[bytes, bytes], now: float) -> None:
        if ticket in self._queue:
            self._queue.remove(ticket)
            ticket.cancelled(now)
            self._done.append(ticket)

    def receive(self, data: CanFrame | None, now: float) -> None:
        if data is None:
            return
        self.seen.append(data)
        if self.broken:
            raise RuntimeError("injected")
        if self._queue:
            self._end(now, lambda t: t.done(data.data, now))

    def advance(self, now: float) -> None:
        if self._queue and now >= self._until:
            self._end(now, lambda t: t.failed(TimeoutError(f"no answer to {t.request.hex()}"), now))
        elif not self._queue:
            self._until = FOREVER

    def _end(self, now: float, how: Any) -> None:
        ticket = self._queue.pop(0)
        how(ticket)
        self._done.append(ticket)
        self._until = FOREVER
        if self._queue:
            self._send(self._queue[0], now)

    def take_output(self, now: float) -> Sequence[CanFrame]:
        out, self._out = self._out, []
        return out

    def take_completed(self) -> Sequence[Ticket[bytes, bytes]]:
        done, self._done = self._done, []
        return done


class Responder:
    """Another node on the channel: answers a frame ``ask`` with ``answer`` and the data plus one."""

    def __init__(self, channel: str, pairs: dict[int, int]) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.pairs = pairs
        self.notifier = can.Notifier(self.bus, [self.on_message], timeout=0.01)

    def on_message(self, message: can.Message) -> None:
        answer = self.pairs.get(message.arbitration_id)
        if answer is not None:
            data = bytes((message.data[0] + 1,))
            self.bus.send(can.Message(arbitration_id=answer, data=data, is_extended_id=False))

    def close(self) -> None:
        self.notifier.stop()
        self.bus.shutdown()


@pytest.fixture
def channel() -> Iterator[str]:
    name = f"can-{uuid.uuid4().hex[:8]}"
    yield name
    assert CAN_BUSES.users(("virtual", name)) == 0


@pytest.fixture
def driver(loop: Scheduler, channel: str) -> Iterator[CanDriver]:
    responder = Responder(channel, {0x601: 0x581, 0x602: 0x582})
    drv = CanDriver.acquire("virtual", channel, loop)
    yield drv
    drv.release()
    responder.close()


def run(loop: Scheduler, driver: CanDriver, engine: AskEngine, *data: bytes) -> list[Ticket[Any, Any]]:
    return loop.run(driver, [ToEngine(engine, d) for d in data], 5.0, "test")


def add(driver: CanDriver, engine: AskEngine) -> None:
    driver.call(lambda now: driver.add(engine, [{"can_id": engine.answer, "can_mask": 0x7FF}]), "add")


def both(driver: CanDriver, first: AskEngine, second: AskEngine) -> None:
    def add_both(now: float) -> None:
        driver.add(first)
        driver.add(second)

    driver.call(add_both, "add")


def closed(driver: CanDriver) -> bool:
    return driver.closed


def test_the_caller_leads_and_starts_no_thread(loop: Scheduler, driver: CanDriver) -> None:
    engine = AskEngine(0x601, 0x581)
    add(driver, engine)
    tickets = run(loop, driver, engine, b"\x01", b"\x10")
    assert [t.result for t in tickets] == [b"\x02", b"\x11"]
    assert not loop.running
    names = [t.name for t in threading.enumerate()]
    assert f"can-reader virtual/{driver.key[1]}" not in names and "starterbus-io" not in names  # the bus's queue
    assert driver.sent == 2 and driver.received >= 2


def test_frames_go_to_the_engines_that_want_them(loop: Scheduler, driver: CanDriver) -> None:
    first, second = AskEngine(0x601, 0x581), AskEngine(0x602, 0x582)
    both(driver, first, second)  # no filters: the bus passes all
    assert run(loop, driver, second, b"\x05")[0].result == b"\x06"
    assert run(loop, driver, first, b"\x07")[0].result == b"\x08"
    assert [f.can_id for f in first.seen] == [0x581] and [f.can_id for f in second.seen] == [0x582]
    dropped = driver.dropped
    sender = can.Bus(interface="virtual", channel=driver.key[1])
    try:
        sender.send(can.Message(arbitration_id=0x123, data=b"\x00", is_extended_id=False))
    finally:
        sender.shutdown()
    assert run(loop, driver, first, b"\x09")[0].result == b"\x0a"  # the foreign frame was read before its answer
    assert driver.dropped == dropped + 1 and len(first.seen) == 2


def test_a_burst_costs_one_wake_up(driver: CanDriver) -> None:
    engine = AskEngine(0x601, 0x581)
    add(driver, engine)
    fd = driver.fd  # a descriptor asked for (a poller outside the loop, other drivers): the reader thread starts
    sender = can.Bus(interface="virtual", channel=driver.key[1])
    try:
        for n in range(100):
            sender.send(can.Message(arbitration_id=0x581, data=bytes((n,)), is_extended_id=False))
        assert wait_until(lambda: driver._reader is not None and driver._reader.queued == 100, 5.0)
    finally:
        sender.shutdown()
    assert os.read(fd, 512) == b"!"  # nobody led meanwhile: one byte for the hundred frames


def test_the_engine_keeps_its_timeouts(loop: Scheduler, driver: CanDriver) -> None:
    silent = AskEngine(0x6FF, 0x5FF, timeout=0.05)  # nobody answers 0x6FF
    add(driver, silent)
    ticket = run(loop, driver, silent, b"\x01")[0]
    assert ticket.state is TicketState.FAILED and "no answer to 01" in str(ticket.error)


def test_an_engine_that_raises_is_contained(loop: Scheduler, driver: CanDriver) -> None:
    broken, healthy = AskEngine(0x602, 0x582, timeout=0.05), AskEngine(0x601, 0x581)
    both(driver, broken, healthy)
    broken.broken = True
    assert run(loop, driver, broken, b"\x01")[0].state is TicketState.FAILED  # its answer raised: then its timeout
    assert any("injected" in text for text in driver.errors)
    assert run(loop, driver, healthy, b"\x03")[0].result == b"\x04"


def test_periodic_outputs_at_the_drivers_deadlines(loop: Scheduler, channel: str) -> None:
    listener = can.Bus(interface="virtual", channel=channel)
    driver = CanDriver.acquire("virtual", channel, loop)
    seen: list[int] = []
    notifier = can.Notifier(listener, [lambda m: seen.append(m.arbitration_id)], timeout=0.01)
    try:
        keep_running(loop)  # nobody waits: the loop's own thread sends them
        assert loop.running
        task = driver.call(lambda now: driver.periodic(CanFrame(0x705, b"\x05"), 0.01, now), "periodic")
        assert wait_until(lambda: seen.count(0x705) >= 3, 5.0)
        driver.call(lambda now: task.stop(), "stop")
        assert driver._periodics == []
    finally:
        let_go(loop)
        notifier.stop()
        listener.shutdown()
        driver.release()
    assert not loop.running  # the thread keep_running started is stopped by the last let_go


def test_one_driver_per_bus_closed_by_its_last_user(loop: Scheduler, channel: str) -> None:
    peer = can.Bus(interface="virtual", channel=channel)
    try:
        first = CanDriver.acquire("virtual", channel, loop)
        second = CanDriver.acquire("virtual", channel, loop)
        assert first is second and CAN_BUSES.users(("virtual", channel)) == 2
        first.release()
        assert not closed(first) and first in loop.drivers
        second.release()
        assert closed(first) and first not in loop.drivers
        assert f"can-reader virtual/{channel}" not in [t.name for t in threading.enumerate()]
    finally:
        peer.shutdown()


def test_what_one_engine_writes_reaches_the_others_that_want_it(loop: Scheduler, driver: CanDriver) -> None:
    asker, listener = AskEngine(0x601, 0x581), AskEngine(0x6AA, 0x601)  # the listener wants the asker's requests
    both(driver, asker, listener)
    assert run(loop, driver, asker, b"\x20")[0].result == b"\x21"
    assert [frame.text() for frame in listener.seen] == ["601#20"]  # as separate sockets on one interface see it
    assert [frame.can_id for frame in asker.seen] == [0x581]  # not its own


class RecordingBus(can.BusABC):
    """A bus of no particular interface, without a descriptor: it records what is sent."""

    def __init__(self) -> None:
        super().__init__(channel="recording")
        self.sent_messages: list[can.Message] = []
        self._quiet = threading.Event()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent_messages.append(msg)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        self._quiet.wait(timeout)  # nothing ever arrives
        return None, False


def test_only_the_virtual_bus_gets_messages_holding_bytes(loop: Scheduler, driver: CanDriver) -> None:
    bus = RecordingBus()
    other = CanDriver(bus, "recording", loop, owns_bus=False)
    try:
        frame = CanFrame(0x601, b"\x01\x02")
        other.write([frame, frame])
        # other interfaces may write into the data (gs_usb pads it, ixxat takes a writable buffer)
        assert [type(m.data) for m in bus.sent_messages] == [bytearray, bytearray]
        assert bytes(bus.sent_messages[0].data) == b"\x01\x02"
    finally:
        other.close()
    engine = AskEngine(0x601, 0x581)
    add(driver, engine)
    assert run(loop, driver, engine, b"\x30")[0].result == b"\x31"  # the responder read the bytes
    data: object = driver._message(CanFrame(0x601, b"\x30")).data  # (python-can declares a bytearray)
    assert type(data) is bytes  # the virtual bus copies them for free
