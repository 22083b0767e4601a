"""How the loop waits for a CAN bus without a descriptor (python-can's virtual bus): alone on the loop, in the bus's
own queue (no reader thread), a wake-up interrupting that wait; beside a driver with a descriptor, through the
bus's reader thread and its pipe. And the driver's one-off ``send`` and its one bit rate per bus."""

from __future__ import annotations

import os
import threading
import uuid
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future
from typing import Any

import can
import pytest

from starterbus.core import CanFrame, ConfigurationError, TransportError
from starterbus.core.engine import FOREVER, Ticket, TicketState
from starterbus.core.media.can import CAN_BUSES, CanDriver, ToEngine
from starterbus.core.media.can_reader import QueueWait
from starterbus.core.media.keeper import keep_running, let_go
from starterbus.core.scheduler import Scheduler

WAIT = 10.0  # s a fake blocker waits when nothing interrupts it (far beyond the loop's own idle wait)


class AskEngine:
    """One request at a time: sends ``CanFrame(ask, data)``, done with the data of the next ``answer`` frame."""

    def __init__(self, ask: int, answer: int) -> None:
        self.ask, self.wanted = ask, frozenset({answer})
        self.deadline = FOREVER
        self._open: list[Ticket[bytes, bytes]] = []
        self._out: list[CanFrame] = []
        self._done: list[Ticket[bytes, bytes]] = []
        self.seen: list[CanFrame] = []

    def submit(self, request: bytes, now: float) -> Ticket[bytes, bytes]:
        ticket: Ticket[bytes, bytes] = Ticket(request)
        ticket.sent(now)
        self._open.append(ticket)
        self._out.append(CanFrame(self.ask, request))
        return ticket

    def cancel(self, ticket: Ticket[bytes, bytes], now: float) -> None:
        if ticket in self._open:
            self._open.remove(ticket)
            ticket.cancelled(now)
            self._done.append(ticket)

    def receive(self, frame: CanFrame | None, now: float) -> None:
        if frame is not None:
            self.seen.append(frame)
            if self._open:
                ticket = self._open.pop(0)
                ticket.done(frame.data, now)
                self._done.append(ticket)

    def advance(self, now: float) -> None:
        pass

    def take_output(self, now: float) -> Sequence[CanFrame]:
        out, self._out = self._out, []
        return out

    def take_completed(self) -> Sequence[Ticket[bytes, bytes]]:
        done, self._done = self._done, []
        return done


class Responder:
    """Another node on the channel: answers 0x601 with 0x581 and the data plus one."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.notifier = can.Notifier(self.bus, [self.on_message], timeout=0.01)

    def on_message(self, message: can.Message) -> None:
        if message.arbitration_id == 0x601:
            data = bytes((message.data[0] + 1,))
            self.bus.send(can.Message(arbitration_id=0x581, data=data, is_extended_id=False))

    def close(self) -> None:
        self.notifier.stop()
        self.bus.shutdown()


def add(driver: CanDriver, engine: AskEngine) -> None:
    driver.call(lambda now: driver.add(engine), "add")


@pytest.fixture
def channel() -> Iterator[str]:
    name = f"can-{uuid.uuid4().hex[:8]}"
    responder = Responder(name)
    yield name
    responder.close()
    assert CAN_BUSES.users(("virtual", name)) == 0


def readers() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith("can-reader")]


class FakeBlocker:
    """A driver that waits by itself: its wait ignores the loop's timeout and ends only when interrupted (or after
    :data:`WAIT`, recorded as ``slept``)."""

    name = "fake"
    fd = -1
    writing = False
    deadline = float("inf")
    can_block = True

    def __init__(self) -> None:
        self._event = threading.Event()
        self.blocks = 0
        self.slept = 0
        self.waiting = threading.Event()

    def block(self, timeout: float) -> bool:
        self.blocks += 1
        self.waiting.set()
        if not self._event.wait(WAIT):
            self.slept += 1
        self._event.clear()
        return False

    def interrupt(self) -> None:
        self._event.set()

    def step(self, now: float, ready: bool) -> None:
        pass

    def submit(self, requests: Sequence[Any], now: float, futures: Sequence[Future[Any] | None]) -> list[Any]:
        return []

    def withdraw(self, tickets: Sequence[Ticket[Any, Any]], now: float) -> None:
        pass

    def cancel(self, futures: Sequence[Future[Any]], now: float) -> None:
        pass

    def crash(self, error: Exception, now: float) -> None:
        pass


class PipeDriver(FakeBlocker):
    """A driver with a descriptor (a pipe nobody writes) and nothing to do."""

    can_block = False

    def __init__(self) -> None:
        super().__init__()
        self.fd, self._w = os.pipe()

    def close(self) -> None:
        os.close(self.fd)
        os.close(self._w)


def constant(n: int) -> Callable[[float], int]:
    return lambda now: n


def test_a_wake_up_interrupts_the_drivers_own_wait(loop: Scheduler) -> None:
    blocker = FakeBlocker()
    loop.call(lambda now: loop.add(blocker))
    keep_running(loop)
    try:
        assert blocker.waiting.wait(WAIT)  # the loop's thread waits in the blocker
        for n in range(3):  # each call reaches the loop at once: its wake-up interrupted the blocker's wait
            assert loop.wait(loop.call(constant(n)), WAIT / 2, "call") == n
    finally:
        let_go(loop)  # (stop wakes the loop: an interrupt too)
    assert blocker.blocks >= 3 and blocker.slept == 0


def test_alone_on_the_loop_a_virtual_bus_has_no_reader_thread(loop: Scheduler, channel: str) -> None:
    driver = CanDriver.acquire("virtual", channel, loop)
    engine = AskEngine(0x601, 0x581)
    try:
        add(driver, engine)
        assert driver.can_block
        keep_running(loop)  # the loop's own thread: every request below interrupts its wait on the bus's queue
        try:
            for n in range(5):
                ticket = loop.wait(loop.submit(driver, ToEngine(engine, bytes((n,)))), 5.0, "ask")
                assert ticket.state is TicketState.DONE and ticket.result == bytes((n + 1,))
            assert f"can-reader virtual/{channel}" not in readers()
        finally:
            let_go(loop)
    finally:
        driver.release()


def test_beside_a_descriptor_the_bus_gets_its_reader(loop: Scheduler, channel: str) -> None:
    other = PipeDriver()
    loop.call(lambda now: loop.add(other))
    driver = CanDriver.acquire("virtual", channel, loop)
    engine = AskEngine(0x601, 0x581)
    try:
        add(driver, engine)
        tickets = loop.run(driver, [ToEngine(engine, b"\x07")], 5.0, "ask")
        assert tickets[0].result == b"\x08"
        assert f"can-reader virtual/{channel}" in readers() and not driver.can_block
    finally:
        driver.release()
        loop.call(lambda now: loop.remove(other))
        loop.wait(loop.call(lambda now: None), 5.0, "turn")
        other.close()
    assert f"can-reader virtual/{channel}" not in readers()


def test_send_writes_in_order_and_the_other_engines_see_it(loop: Scheduler, channel: str) -> None:
    listener = can.Bus(interface="virtual", channel=channel)
    driver = CanDriver.acquire("virtual", channel, loop)
    nmt = AskEngine(0x6AA, 0x000)  # an engine on the same bus that wants NMT frames
    try:
        add(driver, nmt)
        driver.send([CanFrame(0x000, b"\x01\x05"), CanFrame(0x205, b"\x0f\x00")], "start")
        got = [listener.recv(5.0), listener.recv(5.0)]
        assert [(m.arbitration_id, bytes(m.data)) for m in got if m] == [(0x000, b"\x01\x05"), (0x205, b"\x0f\x00")]
        assert [f.text() for f in nmt.seen] == ["000#0105"] and driver.sent == 2
    finally:
        driver.release()
        listener.shutdown()


def test_a_frame_send_refuses_is_a_transport_error_naming_it(
    loop: Scheduler, channel: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    send = can.interfaces.virtual.VirtualBus.send

    def bus_off_for_nmt(
        bus: can.interfaces.virtual.VirtualBus, message: can.Message, timeout: float | None = None
    ) -> None:
        if message.arbitration_id == 0x000:
            raise can.CanError("scripted: bus off")
        send(bus, message, timeout)

    driver = CanDriver.acquire("virtual", channel, loop)
    try:
        monkeypatch.setattr(can.interfaces.virtual.VirtualBus, "send", bus_off_for_nmt)
        with pytest.raises(TransportError) as info:
            driver.send([CanFrame(0x000, b"\x01\x05"), CanFrame(0x205, b"\x0f\x00")], "NMT start")
        assert str(info.value) == (
            f"NMT start: CAN frame 000#0105 not sent on virtual/{channel}: scripted: bus off (1 more not sent)"
        )
        assert driver.sent == 0 and "send 000#0105 failed: scripted: bus off" in driver.errors
    finally:
        driver.release()


def test_one_bus_has_one_bit_rate(loop: Scheduler, channel: str) -> None:
    first = CanDriver.acquire("virtual", channel, loop, 500000)
    try:
        with pytest.raises(ConfigurationError) as info:
            CanDriver.acquire("virtual", channel, loop, 250000)
        message = str(info.value)
        assert f"CAN bus virtual/{channel} is already open in this process at 500000 bit/s" in message
        assert "250000 bit/s refused" in message
        assert CAN_BUSES.users(("virtual", channel)) == 1  # the refused one holds nothing
        same = CanDriver.acquire("virtual", channel, loop, 500000)
        unnamed = CanDriver.acquire("virtual", channel, loop)  # no rate named: joins the bus as it is
        assert same is first and unnamed is first and first.bitrate == 500000
        same.release()
        unnamed.release()
    finally:
        first.release()


def test_the_first_rate_named_is_the_buses(loop: Scheduler, channel: str) -> None:
    first = CanDriver.acquire("virtual", channel, loop)
    try:
        second = CanDriver.acquire("virtual", channel, loop, 250000)
        assert first.bitrate == 250000
        with pytest.raises(ConfigurationError, match="at 250000 bit/s; opening it at 125000 bit/s refused"):
            CanDriver.acquire("virtual", channel, loop, 125000)
        second.release()
    finally:
        first.release()


def test_one_wait_takes_a_whole_burst_and_skips_the_wake_ups(channel: str) -> None:
    bus = can.Bus(interface="virtual", channel=channel)
    sender = can.Bus(interface="virtual", channel=channel)
    try:
        wait = QueueWait.of(bus)
        assert wait is not None and QueueWait.of(sender) is not None
        for n in range(100):
            sender.send(can.Message(arbitration_id=0x581, data=bytes((n,)), is_extended_id=False))
            if n == 50:
                wait.interrupt()
        assert wait.block(5.0)
        assert [m.data[0] for m in wait.take()] == list(range(100))  # all of it in the first wait
        assert not wait.block(0.0) and wait.take() == []
        wait.interrupt()
        assert not wait.block(5.0)  # a wake-up alone ends the wait with nothing read
    finally:
        sender.shutdown()
        bus.shutdown()
