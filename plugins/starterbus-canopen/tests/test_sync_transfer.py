"""A blocking SDO transfer: sent from the caller's own thread while the scheduler waits in the bus's own queue
(``CanDriver.submit_here``), else through the scheduler's thread (the loop waiting in a ``select`` beside another
driver's descriptor); the same values either way."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator, Sequence
from concurrent.futures import Future
from typing import Any

import pytest
from starterbus_canopen.simulator import CanopenSimulator
from starterbus_canopen.transport import CanopenTransport

from starterbus.core import (
    CanFrame,
    Device,
    ManualClock,
    SimulatedStarter,
    StarterbusError,
    Ticket,
    get_profile,
    open_device,
    process_scheduler,
)
from starterbus.testing import wait_until

MODEL = "example_canopen_starter"
SDO_REQUEST = 0x605  # node 5


@pytest.fixture
def device(channel: str) -> Iterator[Device]:
    made = SimulatedStarter(get_profile(MODEL), ManualClock(0.0))
    made.params["current_limit"] = 420
    with CanopenSimulator(("virtual", channel), heartbeat_ms=0) as sim:
        sim.add_node(made, 5)
        with open_device(f"canopen://virtual/{channel}?node=5&heartbeat=0", MODEL) as opened:
            yield opened


def record_writers(device: Device) -> list[int]:
    """The threads that write the node's SDO requests from now on."""
    transport = device.transport
    assert isinstance(transport, CanopenTransport)
    driver = transport.bus.driver
    writers: list[int] = []
    write = driver.write

    def recording(frames: Sequence[CanFrame]) -> None:
        writers.extend(threading.get_ident() for frame in frames if frame.can_id == SDO_REQUEST)
        write(frames)

    driver.write = recording  # type: ignore[method-assign]
    return writers


def test_a_read_sends_its_request_from_the_callers_thread(device: Device) -> None:
    writers = record_writers(device)
    for _ in range(5):
        assert device.read("current_limit")["current_limit"].raw == 420
    assert len(writers) == 5
    # while the scheduler's thread waits in the bus's queue (between reads, all but always) the caller sends
    assert threading.get_ident() in writers


class Pipe:
    """A driver with a descriptor nobody writes: the loop then waits in a select, not in the bus's queue."""

    name = "pipe"
    writing = False
    deadline = float("inf")

    def __init__(self) -> None:
        self.fd, self._w = os.pipe()

    def step(self, now: float, ready: bool) -> None:
        pass

    def submit(self, requests: Sequence[Any], now: float, futures: Sequence[Future[Any] | None]) -> list[Any]:
        return []

    def withdraw(self, tickets: Sequence[Ticket[Any, Any]], now: float) -> None:
        pass

    def cancel(self, futures: Sequence[Future[Any]], now: float) -> None:
        pass

    def crash(self, error: StarterbusError, now: float) -> None:
        pass

    def close(self) -> None:
        os.close(self.fd)
        os.close(self._w)


def test_beside_a_descriptor_a_read_goes_through_the_schedulers_thread(device: Device) -> None:
    loop, pipe = process_scheduler(), Pipe()
    transport = device.transport
    assert isinstance(transport, CanopenTransport)
    loop.wait(loop.call(lambda now: loop.add(pipe)), 5.0, "add")
    try:
        assert wait_until(lambda: not transport.bus.driver.can_block)  # its reader thread started
        writers = record_writers(device)
        for _ in range(3):
            assert device.read("current_limit")["current_limit"].raw == 420
        assert len(writers) == 3 and threading.get_ident() not in writers
    finally:
        loop.wait(loop.call(lambda now: loop.remove(pipe)), 5.0, "remove")
        pipe.close()
