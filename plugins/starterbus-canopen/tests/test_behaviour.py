"""The transport and the simulator over python-can's virtual bus: lost master, SDO aborts and timeouts,
TPDO freshness, URL and profile validation, a fleet polling a canopen device next to a modbus-rtu one."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import canopen
import pytest
from starterbus_canopen.plugin import PLUGIN
from starterbus_canopen.simulator import CanopenSimulator
from starterbus_canopen.transport import CanopenTransport

from starterbus.core import (
    Command,
    ConfigurationError,
    ManualClock,
    Phase,
    RemoteDeviceError,
    SimulatedStarter,
    TimeoutError,
    get_profile,
    open_device,
)
from starterbus.testing import wait_until

MODEL = "example_canopen_starter"


@pytest.fixture
def starter() -> SimulatedStarter:
    return SimulatedStarter(get_profile(MODEL), ManualClock(0.0))


@pytest.fixture
def listener(channel: str) -> Iterator[tuple[canopen.Network, list[tuple[int, bytes]]]]:
    """A bystander on the bus: records every frame it is told to watch, and can send raw frames."""
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.05
    network.connect(interface="virtual", channel=channel)
    seen: list[tuple[int, bytes]] = []
    lock = threading.Lock()

    def keep(can_id: int, data: bytearray, _ts: float) -> None:
        with lock:
            seen.append((can_id, bytes(data)))

    for cob in (0x85, 0x705, 0x185):
        network.subscribe(cob, keep)
    yield network, seen
    network.disconnect()


def test_lost_master_soft_stops_the_run_it_held_and_sends_emcy(
    starter: SimulatedStarter, channel: str, listener: tuple[canopen.Network, list[tuple[int, bytes]]]
) -> None:
    _, seen = listener
    with CanopenSimulator(("virtual", channel), heartbeat_ms=20, consumer_ms=300) as sim:
        sim.add_node(starter, 5)
        url = f"canopen://virtual/{channel}?node=5&heartbeat=20"
        device = open_device(url, starter.profile)
        with device:
            assert device.transport.run_needs_connection
            assert device.start().ok and starter.phase is Phase.STARTING
        # the master is gone: its heartbeat stops, the node's watchdog drops the run command
        assert wait_until(lambda: starter.phase is Phase.STOPPING)
        assert wait_until(lambda: (0x85, bytes([0x30, 0x81, 0x11, 0, 0, 0, 0, 0])) in seen)
        assert "CANopen master heartbeat lost" in starter.events[-1][1]
        assert sim.nodes[5].local.nmt.state == "PRE-OPERATIONAL"  # 0x1029 = 0
        assert any(cob == 0x705 for cob, _ in seen)  # the node's own heartbeat
        # a master back: EMCY reset, NMT start, the node serves again
        with open_device(url, starter.profile) as again:
            assert wait_until(lambda: (0x85, bytes(8)) in seen)
            assert again.status().state.value == "stopping"
            assert sim.nodes[5].local.nmt.state == "OPERATIONAL"


def test_a_motor_started_elsewhere_is_not_stopped_by_the_watchdog(starter: SimulatedStarter, channel: str) -> None:
    with CanopenSimulator(("virtual", channel), heartbeat_ms=0, consumer_ms=100) as sim:
        sim.add_node(starter, 5)
        with open_device(f"canopen://virtual/{channel}?node=5&heartbeat=20", starter.profile) as device:
            device.status()
            starter.start()
        assert wait_until(lambda: sim.nodes[5].master_lost)
        assert starter.phase is Phase.STARTING


def test_sdo_aborts_are_remote_device_errors_with_their_meaning(starter: SimulatedStarter, channel: str) -> None:
    with CanopenSimulator(("virtual", channel), heartbeat_ms=0) as sim:
        sim.add_node(starter, 5)
        with open_device(f"canopen://virtual/{channel}?node=5", starter.profile) as device:
            starter.params["parameter_modify"] = 0
            point = device.profile.point("ramp_time")
            with pytest.raises(RemoteDeviceError) as info:
                device.send_write(point, 20)
            assert info.value.code == 0x08000020 and info.value.protocol == "CANopen SDO"
            assert info.value.meaning == "data cannot be transferred or stored to the application"
            with pytest.raises(RemoteDeviceError) as info:
                device.transport.write_parameter(device.profile.point("status_word"), 1)
            assert info.value.code == 0x06010002 and "read-only" in info.value.meaning
            starter.params["parameter_modify"] = 1
            with pytest.raises(RemoteDeviceError) as info:
                device.transport.write_parameter(point, 500)  # past the guard: the device checks too
            assert info.value.code == 0x06090030
            assert starter.params["ramp_time"] == 10
            identity = device.transport.identify()
            assert identity["product_code"] == 1 and identity["device_type"] == "0x00000000"


def test_a_late_sdo_reply_never_answers_the_next_request(
    channel: str, listener: tuple[canopen.Network, list[tuple[int, bytes]]]
) -> None:
    """A server that answers the first upload late (after the client gave up): the next read gets its own answer."""
    network, _ = listener
    requests: list[bytes] = []

    def reply(value: int) -> None:
        network.send_message(0x585, bytes([0x4B, 0x01, 0x20, 0x00]) + value.to_bytes(2, "little") + b"\0\0")

    def server(_id: int, data: bytearray, _ts: float) -> None:
        requests.append(bytes(data))
        if data[0] == 0x80:  # the client's abort after its timeout: the stale answer comes now, late
            threading.Timer(0.05, reply, (0x1111,)).start()
        elif len(requests) > 2:  # the next request: answered in time, but slower than the stale answer
            threading.Timer(0.1, reply, (0x2222,)).start()

    network.subscribe(0x605, server)
    profile = get_profile(MODEL)
    url = f"canopen://virtual/{channel}?node=5&heartbeat=0&timeout=0.3&max_age=0"
    with open_device(url, profile) as device:
        with pytest.raises(TimeoutError):
            device.read("status_word")
        assert wait_until(lambda: len(requests) >= 2)
        assert requests[1][0] == 0x80 and int.from_bytes(requests[1][4:], "little") == 0x05040000
        assert device.read("status_word")["status_word"].raw == 0x2222


def test_status_uses_fresh_tpdos_but_not_one_older_than_a_command(
    starter: SimulatedStarter, channel: str, listener: tuple[canopen.Network, list[tuple[int, bytes]]]
) -> None:
    network, _ = listener
    with CanopenSimulator(("virtual", channel), heartbeat_ms=0, event_timer=0.02) as sim:
        sim.add_node(starter, 5)
        with open_device(f"canopen://virtual/{channel}?node=5&max_age=5", starter.profile) as device:
            transport = device.transport
            assert isinstance(transport, CanopenTransport)
            assert wait_until(lambda: transport.read_status().source == "canopen TPDO1")
            transport.send_command(Command.START)
            status = transport.read_status()
            assert status.source == "canopen SDO" and status.starting
            assert wait_until(lambda: transport.read_status().source == "canopen TPDO1")
            assert transport.read_status().starting
            bad = transport.bad_tpdos
            network.send_message(0x185, b"\x00")  # a malformed TPDO never yields a value
            assert wait_until(lambda: transport.bad_tpdos == bad + 1)
            assert transport.read_status().starting


@pytest.mark.parametrize(
    ("url", "error"),
    [
        ("canopen://virtual/bus0", "node: required"),
        ("canopen://virtual/bus0?node=0", "node: 0 is outside 1..127"),
        ("canopen://virtual/bus0?node=128", "outside 1..127"),
        ("canopen://virtual?node=5", "expected canopen://INTERFACE/CHANNEL"),
        ("canopen://virtual/bus0?node=5&bitrate=300000", "not a CiA 301 bit rate"),
        ("canopen://virtual/bus0?node=5&master=5", "the device's own node id"),
        ("canopen://virtual/bus0?node=5&speed=1", "unknown URL parameter"),
        ("canopen://virtual/bus0?node=x", "'x' is not an integer"),
    ],
)
def test_bad_urls_are_clear_errors(url: str, error: str) -> None:
    from starterbus.core import DeviceUrl

    with pytest.raises(ConfigurationError, match=error.replace("(", r"\(")):
        PLUGIN.open(DeviceUrl.parse(url), get_profile(MODEL))


def test_a_virtual_channel_nothing_else_is_on_is_refused_with_the_way_across_processes(
    starter: SimulatedStarter, channel: str
) -> None:
    with pytest.raises(ConfigurationError, match="exists only inside one process") as refused:
        open_device(f"canopen://virtual/{channel}?node=5", starter.profile).open()
    assert channel in str(refused.value) and "canopen://socketcan/vcan0?node=N" in str(refused.value)
    with CanopenSimulator(("virtual", channel)) as sim:  # the simulator of this process is a peer
        sim.add_node(starter, 5)
        with open_device(f"canopen://virtual/{channel}?node=5", starter.profile) as device:
            assert device.status().source.startswith("canopen")


@pytest.mark.parametrize("value", [0x2000, [0x2000], [0x0FFF, 0], [0x2000, 256], [0x2000, True], ["0x2000", 0]])
def test_bad_addresses_are_refused(value: object) -> None:
    with pytest.raises(ConfigurationError, match="not a CANopen address"):
        PLUGIN.parse_address(value)


@pytest.mark.parametrize(
    ("settings", "error"),
    [
        ({"node_id": [1, 5]}, "node_id: unknown setting"),
        ({"node_ids": [0, 5]}, "node_ids"),
        ({"device_type": -1}, "device_type"),
        ({"identity": {"vendor": 1}}, "identity.vendor: unknown setting"),
        ({"identity": {"vendor_id": 2**32}}, "identity.vendor_id"),
    ],
)
def test_bad_settings_are_refused(settings: dict[str, object], error: str) -> None:
    with pytest.raises(ConfigurationError, match=error):
        PLUGIN.check_settings(settings)
