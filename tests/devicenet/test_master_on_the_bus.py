"""The master's rules on python-can's virtual bus: one duplicate MAC ID response while on line (communication
fault, typed errors naming the cause, then the automatic reset), a rogue node answering polls, a burst of
foreign traffic, and the ``period`` URL parameter."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator

import can
import pytest

from starterbus.core import Device, ManualClock, MotorState, Profile, SimulatedStarter, open_device
from starterbus.transports.devicenet.codec.ids import poll_command_id, poll_response_id
from starterbus.transports.devicenet.master.link import CommunicationFaultError, DuplicateResponderError, ScannerState
from starterbus.transports.devicenet.simulator import DeviceNetSlaveSimulator
from starterbus.transports.devicenet.transport import DeviceNetTransport

Until = Callable[..., bool]
FAST = "dup_mac_wait=0.05&timeout=0.5&epr=50&poll=10&control=open"  # polled I/O from the open


@pytest.fixture
def simulated(channel: str, jjr8000: Profile) -> Iterator[DeviceNetSlaveSimulator]:
    starter = SimulatedStarter(jjr8000, ManualClock(0.0))
    with DeviceNetSlaveSimulator(starter, ("virtual", channel), 5, dup_mac_wait=0.05) as sim:
        yield sim


def transport(device: Device) -> DeviceNetTransport:
    assert isinstance(device.transport, DeviceNetTransport)
    return device.transport


def send(channel: str, frames: list[tuple[int, str]]) -> None:
    bus = can.Bus(interface="virtual", channel=channel)
    try:
        for can_id, data in frames:
            bus.send(can.Message(arbitration_id=can_id, data=bytes.fromhex(data), is_extended_id=False))
    finally:
        bus.shutdown()


def test_duplicate_mac_response_on_line(channel: str, simulated: object, until: Until) -> None:
    with open_device(f"devicenet://virtual/{channel}?mac=5&{FAST}", "jjr8000") as device:
        t = transport(device)
        scanner, link = t.scanner, t.link
        assert scanner is not None and link is not None
        send(channel, [(0x407, "00341278563412")])  # a request for the master's MAC: answered, stays on line
        assert device.status().state is MotorState.STOPPED and scanner.state is ScannerState.ONLINE
        send(channel, [(0x407, "80341278563412")])  # a response: communication fault
        assert until(lambda: scanner.state is not ScannerState.ONLINE)
        for call in (device.status, device.start, t.identify, lambda: device.read("m3")):
            with pytest.raises(CommunicationFaultError, match="duplicate MAC ID 0 .*vendor 4660") as info:
                call()
            assert "established" not in str(info.value)
        assert t.connection_info()["state"] == "master in communication fault"
        # a single spurious frame costs seconds: the master resets itself and connects again
        assert until(lambda: link.established, 6.0)
        assert device.status().state is MotorState.STOPPED


class RogueResponder:
    """A node answering every poll of MAC ``mac`` without a duplicate MAC ID check (another bus, same channel)."""

    def __init__(self, channel: str, mac: int) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.command = poll_command_id(mac)
        self.answer = can.Message(arbitration_id=poll_response_id(mac), data=b"\xee" * 6, is_extended_id=False)
        self.notifier = can.Notifier(self.bus, [self.on_message], timeout=0.01)

    def on_message(self, message: can.Message) -> None:
        if message.arbitration_id == self.command:
            self.bus.send(self.answer)

    def close(self) -> None:
        self.notifier.stop()
        self.bus.shutdown()


def test_rogue_responder_on_the_bus(channel: str, simulated: object, until: Until) -> None:
    with open_device(f"devicenet://virtual/{channel}?mac=5&{FAST}", "jjr8000") as device:
        link = transport(device).link
        assert link is not None
        rogue = RogueResponder(channel, 5)
        try:
            assert until(lambda: link.duplicate is not None)
            with pytest.raises(DuplicateResponderError, match="EE EE EE EE EE EE"):
                device.status()
            assert transport(device).connection_info()["duplicate_answers"] > 0  # type: ignore[operator]
        finally:
            rogue.close()
        assert until(lambda: link.duplicate is None, 3.0)
        assert device.status().state is MotorState.STOPPED


def test_burst_of_foreign_traffic(channel: str, simulated: object, until: Until) -> None:
    foreign = [(0x3C9, "0102030405"), (0x44D, "0001"), (0x44B, "00CB00"), (0x63F, "FFFFFFFF"), (0x0C1, "01")]
    burst = foreign * 1000
    flood = threading.Thread(target=send, args=(channel, burst))
    # the slave works through the 5,000 frames queued before each poll request (a loaded machine: 0.9 s seen), so
    # its answers may come later than FAST's 0.5 s: what is tested is that none of them is taken for its input
    slow = FAST.replace("timeout=0.5", "timeout=3")
    with open_device(f"devicenet://virtual/{channel}?mac=5&{slow}", "jjr8000") as device:
        scanner = transport(device).scanner
        assert scanner is not None
        flood.start()
        reads = 0
        while flood.is_alive() or reads < 3:
            assert device.status().state is MotorState.STOPPED
            reads += 1
        flood.join()
        # 3C9 and 44B pass the CAN filters (poll response and explicit response groups), the set lookup drops them
        assert until(lambda: scanner.dropped >= 2000)
        assert scanner.state is ScannerState.ONLINE and transport(device).link.established  # type: ignore[union-attr]
        assert device.status().state is MotorState.STOPPED


def test_period_sets_interval_and_expected_packet_rate(channel: str, simulated: object) -> None:
    url = f"devicenet://virtual/{channel}?mac=5&dup_mac_wait=0.05&timeout=0.5&period=1&control=open"
    with open_device(url, "jjr8000") as device:
        link = transport(device).link
        assert link is not None and link.interval == 1.0 and link.epr_ms == 2000
        assert device.status().state is MotorState.STOPPED
        assert "phase_b_current" in device.read("m3")  # the read polls at once (2 settling polls, not 2 s)


def test_a_bug_in_the_machine_does_not_stop_the_driver(
    channel: str, simulated: object, until: Until, monkeypatch: pytest.MonkeyPatch
) -> None:
    with open_device(f"devicenet://virtual/{channel}?mac=5&{FAST}", "jjr8000") as device:
        scanner = transport(device).scanner
        assert scanner is not None

        def broken(*args: object) -> None:
            raise RuntimeError("injected")

        monkeypatch.setattr(scanner.machine, "_on_duplicate_mac", broken)
        send(channel, [(0x407, "00341278563412")])
        assert until(lambda: any("injected" in text for text in scanner.errors))
        assert device.status().state is MotorState.STOPPED  # the thread goes on
