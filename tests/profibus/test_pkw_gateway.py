"""The Modbus TCP gateway channel against real loopback pymodbus servers (a plain one and the simulated gateway)."""

from __future__ import annotations

import asyncio
import socket
import threading
from collections.abc import Callable, Iterator

import pytest
from pymodbus.client import ModbusTcpClient
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from starterbus.core.device import Device, open_device
from starterbus.core.errors import ConfigurationError, RemoteDeviceError, StateRuleError, TransportError
from starterbus.core.profile import Profile
from starterbus.core.simulator import ManualClock, Phase, SimulatedStarter
from starterbus.core.status import Status
from starterbus.transports.modbus.driver.tcp_line import connection_key
from starterbus.transports.profibus_pkw.codec.codes import Ppo
from starterbus.transports.profibus_pkw.driver.channels import GATEWAYS, GatewayChannel
from starterbus.transports.profibus_pkw.master.handshake import PkwError
from starterbus.transports.profibus_pkw.simulator import ProfibusGatewaySimulator
from starterbus.transports.profibus_pkw.slave import SimulatedDpSlave

Factory = type[ProfibusGatewaySimulator]


def settled(dev: Device, done: Callable[[Status], bool], tries: int = 200) -> Status:
    """The status once ``done`` holds: a gateway's input image is as old as its last DP cycle."""
    for _ in range(tries):
        status = dev.status()
        if done(status):
            return status
    return status


@pytest.fixture
def plain_server() -> Iterator[int]:
    """A plain pymodbus TCP server: holding registers 0-99, registers 20-23 preset to 0x0103 612 0x0900 960."""
    values = [0] * 100
    values[20:24] = [0x0103, 612, 0x0900, 960]
    ready = threading.Event()
    ports: list[int] = []
    stops: list[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = []

    async def serve() -> None:
        device = SimDevice(id=0, simdata=[SimData(0, values=values, datatype=DataType.REGISTERS)])
        server = ModbusTcpServer(device, address=("127.0.0.1", 0))
        await server.serve_forever(background=True)
        listener = server.transport  # declared an asyncio.BaseTransport; a listening server is an asyncio.Server
        assert isinstance(listener, asyncio.Server), listener
        ports.append(listener.sockets[0].getsockname()[1])
        stop = asyncio.Event()
        stops.append((asyncio.get_running_loop(), stop))
        ready.set()
        await stop.wait()
        await server.shutdown()  # type: ignore[no-untyped-call]  # pymodbus 3.x leaves shutdown() unannotated

    thread = threading.Thread(target=lambda: asyncio.run(serve()), daemon=True)
    thread.start()
    assert ready.wait(5)
    yield ports[0]
    loop, stop = stops[0]
    loop.call_soon_threadsafe(stop.set)
    thread.join(5)


def test_channel_writes_outputs_and_reads_inputs_of_a_plain_server(plain_server: int) -> None:
    channel = GatewayChannel("127.0.0.1", plain_server, Ppo.PPO1, out=10, inp=20, unit=1)
    try:
        assert channel.exchange([0x0207, 350, 0x0009, 0]) == (0x0103, 612, 0x0900, 960)
        other = ModbusTcpClient("127.0.0.1", port=plain_server)
        try:
            assert other.read_holding_registers(10, count=4, device_id=1).registers == [0x0207, 350, 0x0009, 0]
        finally:
            other.close()  # type: ignore[no-untyped-call]  # pymodbus 3.x leaves ModbusTcpClient.close() unannotated
        snap = channel.snapshot()
        assert snap.inputs == (0x0103, 612, 0x0900, 960) and snap.outputs == (0x0207, 350, 0x0009, 0)
        assert channel.outputs_readable
    finally:
        channel.close()


def test_channel_reads_inputs_with_fc04_when_asked(plain_server: int) -> None:
    # pymodbus' shared register block answers FC04 from the same registers
    channel = GatewayChannel("127.0.0.1", plain_server, Ppo.PPO3, out=30, inp=22, input_function=4)
    try:
        assert channel.exchange([0x0009, 0]) == (0x0900, 960)
        assert "FC04" in channel.describe()
    finally:
        channel.close()


def test_overlapping_areas_cannot_read_outputs_back() -> None:
    channel = GatewayChannel("127.0.0.1", 1, Ppo.PPO1, out=0, inp=2)
    try:
        assert not channel.outputs_readable
    finally:
        channel.close()
    with pytest.raises(ConfigurationError):
        GatewayChannel("127.0.0.1", 1, Ppo.PPO1, input_function=16)
    with pytest.raises(ConfigurationError):
        GatewayChannel("127.0.0.1", 1, Ppo.PPO1, out=65534)


def test_nobody_listening_is_a_transport_error() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed again: nothing listens there
    channel = GatewayChannel("127.0.0.1", port, Ppo.PPO1, timeout=0.5)
    try:
        with pytest.raises(TransportError, match=f"gateway 127.0.0.1:{port}"):
            channel.exchange([0, 0, 0, 0])
    finally:
        channel.close()


# -- the simulated gateway ----------------------------------------------------------------------------------


def test_split_image_read_inputs_write_outputs(gateway_factory: Factory, jjr8000: Profile) -> None:
    starter = SimulatedStarter(jjr8000)
    sim = gateway_factory(starter, port=0, ppo=1, cycle=0.002).start()
    assert sim.port != 0 and sim.client_urls() == {1: sim.url(0)}
    assert sim.url(0) == f"profibus-pkw+gateway://127.0.0.1:{sim.port}?ppo=1&out=0&in=0&unit=1&stale_time=0.004"
    channel = GatewayChannel("127.0.0.1", sim.port, Ppo.PPO1, out=0, inp=0, unit=1)
    try:
        assert channel.snapshot().outputs is None  # same registers: reads show the inputs
        channel.exchange([0x0103, 0, 0x0009, 0])
        for _ in range(200):
            words = channel.exchange([0x0103, 0, 0x0009, 0])
            if words[0] == 0x0103:
                break
        assert words[:2] == (0x0103, 12) and words[2] & 0x0100
        assert sim.output_words(0) == (0x0103, 0, 0x0009, 0) and sim.input_words(0)[:2] == (0x0103, 12)
        assert starter.phase is Phase.STARTING
    finally:
        channel.close()


def test_unmapped_registers_answer_exception_2(gateway_factory: Factory, jjr5000: Profile) -> None:
    sim = gateway_factory(SimulatedStarter(jjr5000), port=0, ppo=3, out=0, inp=10).start()
    channel = GatewayChannel("127.0.0.1", sim.port, Ppo.PPO3, out=4, inp=10)
    try:
        with pytest.raises(RemoteDeviceError) as info:
            channel.exchange([0x0009, 0])
        assert info.value.protocol == "modbus-tcp" and info.value.code == 2
        assert "illegal data address" in str(info.value)
        good = GatewayChannel("127.0.0.1", sim.port, Ppo.PPO3, out=0, inp=10)
        try:
            assert good.snapshot().outputs == (0, 0)  # apart: outputs read back
        finally:
            good.close()
    finally:
        channel.close()


def test_stations_share_one_connection(gateway_factory: Factory, jjr8000: Profile) -> None:
    a, b = SimulatedStarter(jjr8000), SimulatedStarter(jjr8000)
    sim = gateway_factory([a, b], port=0, ppo=1, out=0, inp=100, cycle=0.002, stations=[4, 5]).start()
    urls = sim.client_urls()
    assert urls[5].endswith("out=4&in=104&unit=1&stale_time=0.004")
    with open_device(urls[4] + "&cycle=0", jjr8000) as d4, open_device(urls[5] + "&cycle=0", jjr8000) as d5:
        assert GATEWAYS.users(connection_key("127.0.0.1", sim.port)) == 2
        d5.write("ramp_time", 30)
        d4.write("ramp_time", 40)
        assert (a.params["ramp_time"], b.params["ramp_time"]) == (40, 30)
        d5.start()
        assert b.phase is Phase.STARTING and a.phase is Phase.STOPPED
    assert GATEWAYS.users(connection_key("127.0.0.1", sim.port)) == 0


@pytest.mark.parametrize("model", ["jjr5000", "jjr8000"])
@pytest.mark.parametrize("cycle", ["0", "0.003"])
def test_transport_over_the_gateway(
    model: str, cycle: str, gateway_factory: Factory, profiles: dict[str, Profile]
) -> None:
    profile = profiles[model]
    clock = ManualClock(0.0)
    starter = SimulatedStarter(profile, clock, load=0.5)
    sim = gateway_factory(starter, port=0, ppo=1, cycle=0.002, latency=2).start()
    with open_device(f"{sim.url(0)}&cycle={cycle}&timeout=2", profile) as dev:
        # a write and a read of the same INDL, again and again: every read sees its own write, never a stale echo
        for seconds in (20, 30, 21, 30):
            dev.write("ramp_time", seconds)
            assert dev.read_value("ramp_time").value == seconds
        dev.start()
        clock.advance(0.5)
        status = settled(dev, lambda s: s.currents["a"].value > 0)
        assert status.starting and status.currents["a"].value > 0
        values = dev.read("phase_a_current", "status_word")
        assert values["status_word"].raw & 0x0100
        clock.advance(120)
        if model == "jjr8000":
            with pytest.raises(StateRuleError):  # the guard knows the motor runs: nothing sent
                dev.write("current_limit", 4.0)
            with pytest.raises(PkwError) as info:  # past the guard, the device's own refusal
                dev.send_write(*dev.validate_write("current_limit", 4.0))
            assert (info.value.code, info.value.meaning) == (3, "cannot modify while running")
        dev.stop()
        assert starter.phase in (Phase.STOPPING, Phase.STOPPED)
        starter.inject_fault(7)
        assert settled(dev, lambda s: s.fault).fault_code == 7
        dev.reset()
        assert not settled(dev, lambda s: not s.fault).fault
    assert starter.phase is Phase.STOPPED


def test_ppo3_over_the_gateway_and_a_reconnect(gateway_factory: Factory, jjr5000: Profile) -> None:
    starter = SimulatedStarter(jjr5000)
    sim = gateway_factory(starter, port=0, ppo=3, cycle=0.002).start()
    url = sim.url(0) + "&cycle=0.003"
    with open_device(url, jjr5000) as dev:
        dev.start()
        assert settled(dev, lambda s: s.starting).starting
    # a second session adopts the control word in force: the motor keeps running
    with open_device(url, jjr5000) as dev:
        assert dev.status().starting and starter.phase is Phase.STARTING
        dev.stop()
    assert starter.phase is not Phase.STARTING


def test_gateway_simulator_rejects_bad_layouts(jjr5000: Profile) -> None:
    starter = SimulatedStarter(jjr5000)
    with pytest.raises(ConfigurationError):
        ProfibusGatewaySimulator([], port=0)
    with pytest.raises(ConfigurationError):
        ProfibusGatewaySimulator(starter, cycle=0)
    with pytest.raises(ConfigurationError):
        ProfibusGatewaySimulator(starter, out=65534)
    with pytest.raises(ConfigurationError):
        ProfibusGatewaySimulator([starter], stations=[1, 2])
    with pytest.raises(ConfigurationError):
        ProfibusGatewaySimulator(SimulatedDpSlave(starter, Ppo.PPO3), ppo=1)


def test_a_busy_port_is_reported(gateway_factory: Factory, jjr5000: Profile) -> None:
    first = gateway_factory(SimulatedStarter(jjr5000), port=0).start()
    with pytest.raises(TransportError, match="could not listen"):
        ProfibusGatewaySimulator(SimulatedStarter(jjr5000), port=first.port).start(timeout=2)
