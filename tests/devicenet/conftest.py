"""Fixtures for the DeviceNet tests: unique virtual channels, checked closed after each test."""

from __future__ import annotations

import uuid
from collections.abc import Callable, Iterator

import can
import pytest
from can.interfaces import virtual

from starterbus.core import CanFrame
from starterbus.testing import wait_until
from starterbus.transports.devicenet.driver.canbus import from_message
from starterbus.transports.devicenet.transport import SCANNERS


@pytest.fixture
def channel(request: pytest.FixtureRequest) -> Iterator[str]:
    """A virtual CAN channel no other test uses; the test must leave no bus open on it."""
    name = f"dn-{request.node.name[:30]}-{uuid.uuid4().hex[:6]}"
    yield name
    key = ("virtual", name)
    assert SCANNERS.users(key) == 0, f"a scanner on {name} was left open"
    assert name not in virtual.channels, f"a python-can bus on {name} was left open"


class Sniffer:
    """Records every frame on a virtual channel (a listening bus, as a bus analyser would)."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.frames: list[CanFrame] = []
        self._notifier = can.Notifier(self.bus, [self._on_message], timeout=0.01)

    def _on_message(self, message: can.Message) -> None:
        frame = from_message(message)
        if frame is not None:
            self.frames.append(frame)

    def texts(self) -> list[str]:
        """Frames as candump text, with the transaction id bit of explicit headers cleared (the scanner
        toggles it per request) so that tests can compare with fixed frames."""
        out = []
        for frame in list(self.frames):
            data = frame.data
            if 0x400 <= frame.can_id < 0x600 and frame.can_id & 7 in (3, 4, 6) and data:
                data = bytes((data[0] & ~0x40 & 0xFF,)) + data[1:]
            out.append(CanFrame(frame.can_id, data).text())
        return out

    def ids(self) -> list[int]:
        return [frame.can_id for frame in list(self.frames)]

    def close(self) -> None:
        self._notifier.stop()
        self.bus.shutdown()


@pytest.fixture
def sniffer(channel: str) -> Iterator[Sniffer]:
    sniff = Sniffer(channel)
    yield sniff
    sniff.close()


@pytest.fixture
def until() -> Callable[..., bool]:
    return wait_until
