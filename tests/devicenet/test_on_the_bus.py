"""Master (scanner) and simulated JJR8000 slaves on python-can's virtual bus: start-up, identity, commands,
measurements, watchdog, collisions, a master restart, a slave that goes away and comes back."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from starterbus.core import (
    Command,
    ConfigurationError,
    Device,
    ManualClock,
    MotorState,
    Phase,
    Profile,
    RemoteDeviceError,
    SimulatedStarter,
    TimeoutError,
    TransportError,
    UnsupportedOperationError,
    open_device,
)
from starterbus.testing import wait_until
from starterbus.transports.devicenet.codec.assemblies import AssemblySet
from starterbus.transports.devicenet.codec.cip import Service
from starterbus.transports.devicenet.codec.explicit import ExplicitRequest
from starterbus.transports.devicenet.driver.scanner import Scanner
from starterbus.transports.devicenet.master.link import LinkConfig, LinkState, ScannerConfig, ScannerState
from starterbus.transports.devicenet.simulator import DeviceNetSimulator, DeviceNetSlaveSimulator
from starterbus.transports.devicenet.slave.state import NodeState
from starterbus.transports.devicenet.transport import SCANNERS, ControlConflictError, DeviceNetTransport

FAST = "dup_mac_wait=0.05&timeout=0.5&epr=50&poll=10&control=open"  # polled I/O from the open
Until = Callable[..., bool]


def url(channel: str, mac: int, extra: str = "") -> str:
    query: dict[str, str] = {}
    for part in f"{FAST}&{extra}".split("&"):
        if part:
            key, _, value = part.partition("=")
            query[key] = value
    return f"devicenet://virtual/{channel}?mac={mac}&" + "&".join(f"{k}={v}" for k, v in query.items())


@pytest.fixture
def starters(jjr8000: Profile) -> dict[int, SimulatedStarter]:
    return {5: SimulatedStarter(jjr8000, ManualClock(0.0)), 6: SimulatedStarter(jjr8000, ManualClock(0.0))}


@pytest.fixture
def two_slaves(channel: str, starters: dict[int, SimulatedStarter]) -> Iterator[list[DeviceNetSlaveSimulator]]:
    """Two slave simulators, each with its own bus on the channel (they see each other's frames)."""
    sims = [DeviceNetSlaveSimulator(starters[mac], ("virtual", channel), mac, dup_mac_wait=0.05) for mac in (5, 6)]
    for sim in sims:
        sim.start()
    yield sims
    for sim in sims:
        sim.close()


def transport(device: Device) -> DeviceNetTransport:
    assert isinstance(device.transport, DeviceNetTransport)
    return device.transport


def test_startup_of_two_slaves_and_one_master(
    channel: str,
    sniffer: object,
    two_slaves: list[DeviceNetSlaveSimulator],
    starters: dict[int, SimulatedStarter],
    until: Until,
) -> None:
    with open_device(url(channel, 5), "jjr8000") as d5, open_device(url(channel, 6), "jjr8000") as d6:
        assert SCANNERS.users(("virtual", channel)) == 2  # one scanner for both devices
        assert d5.status().state is MotorState.STOPPED
        assert d6.status().bus_control is True  # network control: DeviceNet commands set control word bit 3
        d5.start()
        assert d5.status().state is MotorState.STARTING
        assert d6.status().state is MotorState.STOPPED
        assert starters[5].phase is Phase.STARTING and starters[6].phase is Phase.STOPPED
    released = ["42B#00CC", "433#00CC"]  # the last frames: wait until the listening bus has them
    assert until(lambda: all(frame in sniffer.texts() for frame in released))  # type: ignore[attr-defined]
    texts = sniffer.texts()  # type: ignore[attr-defined]
    # duplicate MAC ID checks: each node twice, the master (MAC 0, vendor 0) twice
    assert sum(t.startswith("42F#0033030501") for t in texts) == 2
    assert sum(t.startswith("437#0033030601") for t in texts) == 2
    assert sum(t.startswith("407#000000") for t in texts) == 2
    for mac, base in ((5, 0x428), (6, 0x430)):
        request, response, command, poll_response = (f"{base + n:03X}#" for n in (4, 3, 5, 0))
        poll_response = f"{0x3C0 + mac:03X}#"
        sequence = [
            f"{base + 6:03X}#004B03010100",  # Allocate explicit on the group 2 only port: monitoring
            f"{response}00CB00",
            f"{request}000E050109",  # the explicit connection's expected packet rate
            f"{request}000E046503",  # input assembly 101 over explicit messaging: no output data
            f"{base + 6:03X}#004B03010200",  # control=open: Allocate polled, the motor being stopped
            f"{request}000E050207",  # produced size
            f"{response}008E0600",
            f"{request}000E050208",  # consumed size
            f"{response}008E0200",
            f"{request}00100502093200",  # expected packet rate 50 ms
            f"{response}00903200",
        ]
        positions = [texts.index(frame) for frame in sequence]
        assert positions == sorted(positions)
        first_poll = next(i for i, t in enumerate(texts) if t.startswith(command))
        assert first_poll > positions[-1]
        assert any(t.startswith(poll_response) and len(t) == 4 + 12 for t in texts)
        assert f"{request}004C030103" in texts  # released on close
        assert f"{response}00CC" in texts
    for sim in two_slaves:
        assert sim.slave.allocation == 0


def test_identity_with_fragmented_product_name(channel: str, sniffer: object, two_slaves: object, until: Until) -> None:
    with open_device(url(channel, 6), "jjr8000") as device:
        identity = transport(device).identify()
    assert identity == {
        "mac": 6,
        "vendor_id": 819,
        "device_type": 45,
        "product_code": 1,
        "revision": "1.1",
        "status": "0x0001",
        "serial_number": "0x20110106",
        "product_name": "JJR8000",
        "input_assembly": 101,
        "output_assembly": 102,
        "io_connection": "held",
        "expected_packet_rate_ms": 50,
    }
    assert until(lambda: "434#80C100" in sniffer.texts())  # type: ignore[attr-defined]
    texts = sniffer.texts()  # type: ignore[attr-defined]
    first = texts.index("433#80008E074A4A5238")  # first fragment of the product name
    rest = texts[first + 1 :]
    assert rest.index("434#80C000") < rest.index("433#80813030 30".replace(" ", "")) < rest.index("434#80C100")


def test_commands_measurements_and_fault_reset(
    channel: str, two_slaves: object, starters: dict[int, SimulatedStarter]
) -> None:
    starter = starters[5]
    with open_device(url(channel, 5), "jjr8000") as device:
        device.start()
        starter.clock.advance(1.0)  # type: ignore[attr-defined]
        values = device.read("m3", "status_word", "phase_a_current", "start_count")
        assert values["phase_b_current"].raw == starter.read(starter.profile.point("m3"))
        assert values["phase_b_current"].resolution == 0.1  # a status parameter keeps the 0.1 A of appendix 2
        assert values["status_word"].raw & 0x0100  # soft starting
        assert values["start_count"].value == 1
        status = device.status()
        assert status.currents["a"].resolution == 1.0  # the assembly's L1 current is in whole A
        assert status.currents["a"].raw == round(starter.current())
        starter.inject_fault(6)
        assert wait_until(lambda: device.status().fault, 2.0)
        status = device.status()
        assert (status.fault_code, status.fault_text) == (6, "motor overload")
        device.reset()
        assert starter.phase is Phase.STOPPED and starter.fault_code is None
        assert wait_until(lambda: not device.status().fault, 2.0)
        device.stop()
        with pytest.raises(UnsupportedOperationError):
            device.read("motor_rated_current")  # parameters are not reachable over DeviceNet
        with pytest.raises(UnsupportedOperationError):
            device.write("ramp_time", 10)
        with pytest.raises(UnsupportedOperationError):
            device.command(Command.RELEASE_BUS_CONTROL)


def test_basic_assemblies(channel: str, jjr8000: Profile) -> None:
    starter = SimulatedStarter(jjr8000, ManualClock(0.0))
    with DeviceNetSlaveSimulator(starter, ("virtual", channel), 7, dup_mac_wait=0.05, assemblies=AssemblySet.BASIC):
        with pytest.raises(ConfigurationError, match="basic assemblies"):
            open_device(url(channel, 7, "assemblies=extended"), "jjr8000").open()
        with open_device(url(channel, 7), "jjr8000") as device:  # auto
            starter.clock.advance(100.0)  # type: ignore[attr-defined]
            device.start()
            starter.clock.advance(100.0)  # type: ignore[attr-defined]
            assert wait_until(lambda: device.status().running, 2.0)
            status = device.status()
            assert status.at_reference is True and status.fault_code is None
            value = device.read("phase_a_current")["phase_a_current"]
            assert (value.resolution, value.value) == (1.0, round(starter.current()))
            with pytest.raises(UnsupportedOperationError, match="extended"):
                device.read("m3")
            assert transport(device).preview_command(Command.FAULT_RESET) == ["43D#04", "43D#00"]


def test_watchdog_and_master_restart_with_the_old_allocation(
    channel: str, sniffer: object, jjr8000: Profile, until: Until
) -> None:
    starter = SimulatedStarter(jjr8000, ManualClock(0.0))
    with DeviceNetSlaveSimulator(starter, ("virtual", channel), 5, dup_mac_wait=0.05) as sim:
        config = ScannerConfig("virtual", channel, poll_period=0.01, dup_mac_wait=0.05, timeout=0.5)
        first = Scanner(config)
        first.wait_online(2)
        # the slave on line too: an Allocate sent before its duplicate MAC check ends goes unanswered and is sent
        # again (the frame counts below count one)
        assert sim.wait_online(2)
        link = first.attach(LinkConfig(5, epr_ms=30))
        assert until(lambda: link.established)
        first.set_outputs(link, run=True)
        assert until(lambda: starter.phase is Phase.STARTING)
        first.abandon()  # the master crashes: no release, no more polls
        assert until(lambda: starter.phase is Phase.STOPPING, 1.0)  # 4 x 30 ms later: soft stop
        node = sim.slave
        assert any("timed out" in text for _, text in node.events)
        assert node.allocation == 0x03 and node.master_mac == 0  # the slave still holds the old allocation
        # the master comes back with the same MAC: "already allocated" -> release -> allocate
        with open_device(url(channel, 5), "jjr8000") as device:
            assert device.status().state is MotorState.STOPPING
            assert until(lambda: sniffer.texts().count("42E#004B03010200") == 2)  # type: ignore[attr-defined]
            texts = sniffer.texts()  # type: ignore[attr-defined]
            assert "42B#00940B02" in texts  # already in requested mode: our own old allocation
            # explicit: one release, then the second Allocate; the same for polled (control=open)
            assert texts.count("42E#004C030101") == 1 and texts.count("42E#004B03010100") == 2
            assert texts.count("42C#004C030102") == 1 and texts.count("42E#004B03010200") == 2
            assert texts.count("42E#004B03010300") == 1  # the first master's
            assert transport(device).link is not None and not transport(device).link.run  # type: ignore[union-attr]


def test_another_master_is_refused(channel: str, jjr8000: Profile, until: Until) -> None:
    simulator = DeviceNetSlaveSimulator(SimulatedStarter(jjr8000), ("virtual", channel), 5, dup_mac_wait=0.05)
    with simulator, open_device(url(channel, 5), "jjr8000") as device:
        other = Scanner(ScannerConfig("virtual", channel, master_mac=1, dup_mac_wait=0.05, timeout=0.5))
        try:
            other.wait_online(2)
            link = other.attach(LinkConfig(5, epr_ms=50))
            assert until(lambda: link.state is LinkState.REFUSED)
            error = link.last_error
            assert isinstance(error, RemoteDeviceError)
            assert (error.code, error.additional) == (0x0C, 0x01)
            assert "another master" in str(error)
            assert device.status().state is MotorState.STOPPED  # the first master keeps its slave
        finally:
            other.close()


def test_slave_goes_away_and_comes_back(channel: str, jjr8000: Profile, until: Until) -> None:
    starter = SimulatedStarter(jjr8000, ManualClock(0.0))
    sim = DeviceNetSlaveSimulator(starter, ("virtual", channel), 5, dup_mac_wait=0.05).start()
    with open_device(url(channel, 5), "jjr8000") as device:
        device.start()
        sim.close()  # power off: silence
        link = transport(device).link
        assert link is not None
        assert until(lambda: link.state is LinkState.LOST, 2.0)
        assert not link.run  # the start command was dropped
        with pytest.raises(TimeoutError, match="no explicit connection"):
            device.status()
        with pytest.raises(TimeoutError):
            device.start()
        sim = DeviceNetSlaveSimulator(starter, ("virtual", channel), 5, dup_mac_wait=0.05).start()
        try:
            assert until(lambda: link.established, 3.0)  # re-allocated (monitoring)
            # the master dropped its run command with the slave, but this starter kept starting (its module came
            # back, the motor never stopped): control=open does not take control with run = 0 while it runs
            assert device.status().state is MotorState.STARTING and not link.polling
            with pytest.raises(ControlConflictError, match="starting under another control"):
                device.read("m3")
            device.stop()  # an operator's stop takes control on purpose
            assert starter.phase in (Phase.STOPPING, Phase.STOPPED)
            starter.clock.advance(100.0)  # type: ignore[attr-defined]  # the soft stop ends
            device.start()
            assert wait_until(lambda: device.status().state is MotorState.STARTING, 2.0)
        finally:
            sim.close()


def test_duplicate_mac_collision_between_slaves(channel: str, jjr8000: Profile, until: Until) -> None:
    first = DeviceNetSlaveSimulator(SimulatedStarter(jjr8000), ("virtual", channel), 9, dup_mac_wait=0.05).start()
    second = DeviceNetSlaveSimulator(SimulatedStarter(jjr8000), ("virtual", channel), 9, dup_mac_wait=0.05)
    try:
        assert first.wait_online(2) and first.slave.state is NodeState.ONLINE
        second.start()
        assert second.wait_online(2)
        assert second.slave.state is NodeState.COMM_FAULT  # the on-line node answered its check
        assert "duplicate MAC ID 9" in second.slave.fault_reason
        assert first.slave.state is NodeState.ONLINE
    finally:
        first.close()
        second.close()


def test_simultaneous_start_with_the_same_mac(channel: str, jjr8000: Profile) -> None:
    sim = DeviceNetSimulator(("virtual", channel), dup_mac_wait=0.05)
    a = sim.add_node(SimulatedStarter(jjr8000), 9)
    b = sim.add_node(SimulatedStarter(jjr8000), 9)
    with sim:
        assert sim.wait_online(2)
        assert a.state is NodeState.COMM_FAULT and b.state is NodeState.COMM_FAULT


def test_master_mac_collision(channel: str, jjr8000: Profile) -> None:
    with DeviceNetSlaveSimulator(SimulatedStarter(jjr8000), ("virtual", channel), 0, dup_mac_wait=0.05) as sim:
        assert sim.wait_online(2)
        with pytest.raises(TransportError, match="duplicate MAC ID 0"):
            open_device(url(channel, 5), "jjr8000").open()
        assert SCANNERS.users(("virtual", channel)) == 0


def test_absent_slave_times_out_on_open(channel: str, sniffer: object) -> None:
    """Another bus is on the channel (a bus analyser), but no slave answers at MAC 12."""
    with pytest.raises(TimeoutError, match="did not answer"):
        open_device(url(channel, 12, "timeout=0.1"), "jjr8000").open()


def test_a_virtual_channel_nothing_else_is_on_is_refused_with_the_way_across_processes(
    channel: str, jjr8000: Profile
) -> None:
    with pytest.raises(ConfigurationError, match="exists only inside one process") as refused:
        open_device(url(channel, 5), "jjr8000").open()
    assert channel in str(refused.value) and "devicenet://remote/127.0.0.1:54701?mac=N" in str(refused.value)
    assert SCANNERS.users(("virtual", channel)) == 0
    simulator = DeviceNetSlaveSimulator(SimulatedStarter(jjr8000), ("virtual", channel), 5, dup_mac_wait=0.05)
    with simulator, open_device(url(channel, 5), "jjr8000") as device:  # the simulator of this process is a peer
        assert device.status().source == "devicenet"


def test_scanner_settings_must_agree(channel: str, two_slaves: object) -> None:
    with open_device(url(channel, 5), "jjr8000"):
        with pytest.raises(ConfigurationError, match="master_mac=0"):
            open_device(url(channel, 6, "master_mac=2"), "jjr8000").open()
        with pytest.raises(ConfigurationError, match="already open"):
            open_device(url(channel, 5), "jjr8000").open()


def test_scanner_state_after_close(channel: str, two_slaves: object) -> None:
    device = open_device(url(channel, 5), "jjr8000").open()
    scanner = transport(device).scanner
    device.close()
    assert scanner is not None and scanner.state is ScannerState.CLOSED
    with pytest.raises(ConfigurationError, match="not open"):
        device.status()


def test_fragmented_request_from_the_master(channel: str, sniffer: object, two_slaves: object, until: Until) -> None:
    """Master -> slave fragmentation over the bus: a 17-byte Set_Attribute_Single in three acknowledged fragments."""
    with open_device(url(channel, 5), "jjr8000") as device:
        scanner, link = transport(device).scanner, transport(device).link
        assert scanner is not None and link is not None
        request = ExplicitRequest(0, Service.SET_ATTRIBUTE_SINGLE, 1, 1, 7, b"\x0bJJR8000-XYZ")
        with pytest.raises(RemoteDeviceError) as info:
            scanner.request(link, request)
        assert info.value.code == 0x0E  # reassembled by the slave, then refused: not settable
    assert until(lambda: "42B#00940EFF" in sniffer.texts())  # type: ignore[attr-defined]
    texts = sniffer.texts()  # type: ignore[attr-defined]
    first = texts.index("42C#8000100101070B4A")  # service, class, instance, attribute 7, length, "J"
    rest = texts[first:]
    assert rest.index("42B#80C000") < rest.index("42C#80414A5238303030") < rest.index("42B#80C100")
    assert rest.index("42C#80822D58595A") < rest.index("42B#80C200") < rest.index("42B#00940EFF")


def test_node_added_to_a_running_simulator(channel: str, sniffer: object, jjr8000: Profile, until: Until) -> None:
    with DeviceNetSimulator(("virtual", channel), dup_mac_wait=60.0) as sim:
        node = sim.add_node(SimulatedStarter(jjr8000), 17)
        texts: Callable[[], list[str]] = sniffer.texts  # type: ignore[attr-defined]
        assert until(lambda: len(texts()) >= 1, 10.0)  # its first check request goes out at once, not after 60 s
        assert len(texts()) == 1 and texts()[0].startswith("48F#00330311")  # the second one waits 60 s
        assert node.state is NodeState.CHECKING


def test_explicit_connection_is_kept_alive(channel: str, jjr8000: Profile, until: Until) -> None:
    """A slave whose explicit connection times out after 4 x 60 ms: the scanner reads its EPR and keeps it alive."""
    simulator = DeviceNetSlaveSimulator(
        SimulatedStarter(jjr8000), ("virtual", channel), 5, dup_mac_wait=0.05, explicit_epr_ms=60
    )
    with simulator, open_device(url(channel, 5), "jjr8000") as device:
        link = transport(device).link
        assert link is not None and link.explicit_epr_ms == 60 and link.keepalive == pytest.approx(0.08)
        counters = simulator.slave.counters
        seen = counters.explicit_requests
        # eight keep-alive reads, 80 ms apart: well past the 240 ms the connection would last without them
        assert until(lambda: counters.explicit_requests >= seen + 8 or simulator.slave.allocation == 0, 5.0)
        assert simulator.slave.allocation == 0x03  # still allocated: the keep-alive reads arrived in time
        assert transport(device).identify()["product_name"] == "JJR8000"
