"""Devices on one CAN bus share one CAN driver, one master heartbeat and one SDO engine per node id; what
must be equal on a bus (bit rate, a master's heartbeat period) is checked, and a refused device leaves nothing."""

from __future__ import annotations

from collections.abc import Iterator

import can
import pytest
from starterbus_canopen.bus import BUSES, CanBus
from starterbus_canopen.simulator import CanopenSimulator
from starterbus_canopen.transport import CanopenTransport

from starterbus.core import ConfigurationError, Device, ManualClock, SimulatedStarter, TransportError, get_profile
from starterbus.core import open_device as _open_device

MODEL = "example_canopen_starter"


def open_device(url: str) -> Device:
    return _open_device(url, MODEL)


def starter(current_limit: int) -> SimulatedStarter:
    made = SimulatedStarter(get_profile(MODEL), ManualClock(0.0))
    made.params["current_limit"] = current_limit
    return made


@pytest.fixture
def two_nodes(channel: str) -> Iterator[CanopenSimulator]:
    """Node 5 (current_limit 420) and node 6 (380) on ``channel``."""
    with CanopenSimulator(("virtual", channel), heartbeat_ms=0) as sim:
        sim.add_node(starter(420), 5)
        sim.add_node(starter(380), 6)
        yield sim


def bus_of(device: Device) -> CanBus:
    transport = device.transport
    assert isinstance(transport, CanopenTransport)
    return transport.bus


def test_two_devices_on_one_bus_share_its_network_and_their_master_heartbeat(
    channel: str, two_nodes: CanopenSimulator
) -> None:
    key = ("virtual", channel)
    first = open_device(f"canopen://virtual/{channel}?node=5&heartbeat=50").open()
    second = open_device(f"canopen://virtual/{channel}?node=6&heartbeat=50").open()
    try:
        bus = bus_of(first)
        assert bus_of(second) is bus and BUSES.leases()[key] == 2
        master = first.transport.options.master  # type: ignore[attr-defined]
        assert bus.heartbeats() == {master: 0.05}  # one heartbeat for the master, not one per device
        assert (bus.users(5), bus.users(6)) == (1, 1)
        assert first.read("current_limit")["current_limit"].raw == 420
        assert second.read("current_limit")["current_limit"].raw == 380
        first.close()
        assert bus.users(5) == 0 and BUSES.leases()[key] == 1
        assert bus.heartbeats() == {master: 0.05}  # the other device still needs it
        assert second.read("current_limit")["current_limit"].raw == 380
        assert second.status().state.value == "ready"
    finally:
        first.close()
        second.close()
    assert key not in BUSES.leases()
    assert bus.heartbeats() == {} and bus.closed and bus.driver.closed  # the last device closed the bus


def test_one_node_opened_twice_keeps_answering_the_one_still_open(channel: str) -> None:
    with CanopenSimulator(("virtual", channel), heartbeat_ms=0) as sim:
        sim.add_node(starter(420), 5)
        url = f"canopen://virtual/{channel}?node=5&heartbeat=0&timeout=0.3"
        with open_device(url) as first:
            with open_device(url) as second:
                assert bus_of(first).users(5) == 2
                assert second.read("current_limit")["current_limit"].raw == 420
            # closing the second did not take the node's SDO answers away from the first
            assert bus_of(first).users(5) == 1
            assert first.read("current_limit")["current_limit"].raw == 420


def test_another_bit_rate_on_an_open_bus_is_refused_and_leaves_nothing(
    channel: str, two_nodes: CanopenSimulator
) -> None:
    key = ("virtual", channel)
    with open_device(f"canopen://virtual/{channel}?node=5&bitrate=250000&heartbeat=0") as first:
        other = open_device(f"canopen://virtual/{channel}?node=6&bitrate=500000&heartbeat=0")
        with pytest.raises(ConfigurationError) as info:
            other.open()
        message = str(info.value)
        assert "already open in this process at 250000 bit/s" in message and "500000 bit/s" in message
        assert "node=6" in message
        assert BUSES.leases()[key] == 1 and bus_of(first).users(6) == 0
        default = open_device(f"canopen://virtual/{channel}?node=6&heartbeat=0")
        with pytest.raises(ConfigurationError, match="the interface's default bit rate"):
            default.open()
        assert first.read("current_limit")["current_limit"].raw == 420
    assert key not in BUSES.leases()


def test_another_heartbeat_period_for_the_same_master_is_refused(channel: str, two_nodes: CanopenSimulator) -> None:
    key = ("virtual", channel)
    with open_device(f"canopen://virtual/{channel}?node=5&heartbeat=50") as first:
        bus = bus_of(first)
        with pytest.raises(ConfigurationError, match="every 50 ms .* asks for 100 ms"):
            open_device(f"canopen://virtual/{channel}?node=6&heartbeat=100").open()
        assert BUSES.leases()[key] == 1 and bus.users(6) == 0 and len(bus.heartbeats()) == 1
        # no heartbeat asked for: no conflict; another master id: a heartbeat of its own
        with open_device(f"canopen://virtual/{channel}?node=6&heartbeat=0") as quiet:
            assert quiet.read("current_limit")["current_limit"].raw == 380
        with open_device(f"canopen://virtual/{channel}?node=6&heartbeat=100&master=126") as other:
            assert other.read("current_limit")["current_limit"].raw == 380
            master = first.transport.options.master  # type: ignore[attr-defined]
            assert bus.heartbeats() == {master: 0.05, 126: 0.1}
        assert bus.heartbeats() == {master: 0.05}


def test_an_interface_that_cannot_be_opened_is_a_transport_error_and_leaves_nothing() -> None:
    device = open_device("canopen://no_such_interface/can9?node=5")
    with pytest.raises(TransportError, match=r"canopen://no_such_interface/can9\?node=5 \(node 5\): cannot open CAN"):
        device.open()
    assert ("no_such_interface", "can9") not in BUSES.leases()


def test_a_failing_nmt_start_is_a_transport_error_and_leaves_nothing(
    channel: str, two_nodes: CanopenSimulator, monkeypatch: pytest.MonkeyPatch
) -> None:
    send = can.interfaces.virtual.VirtualBus.send

    def bus_off_for_nmt(
        bus: can.interfaces.virtual.VirtualBus, message: can.Message, timeout: float | None = None
    ) -> None:
        if message.arbitration_id == 0x000:
            raise can.CanError("scripted: bus off")
        send(bus, message, timeout)

    monkeypatch.setattr(can.interfaces.virtual.VirtualBus, "send", bus_off_for_nmt)
    with pytest.raises(
        TransportError,
        match=r"heartbeat=50 \(node 5\): NMT start: CAN frame 000#0105 not sent on virtual/.*: scripted: bus off",
    ):
        open_device(f"canopen://virtual/{channel}?node=5&heartbeat=50").open()
    assert ("virtual", channel) not in BUSES.leases()
