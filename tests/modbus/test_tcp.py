"""``modbus-tcp``: MBAP against our gateway simulator and against pymodbus's own TCP server as an independent
peer; transaction ids (a stale answer is never a value), one connection per gateway, outstanding requests, the
gateway's 0x0A / 0x0B, reconnection."""

from __future__ import annotations

import asyncio
import socket
import threading
from collections.abc import Iterator

import pytest
from pymodbus.client import ModbusTcpClient
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from starterbus.core.device import open_device
from starterbus.core.errors import ConfigurationError, RemoteDeviceError, TimeoutError, TransportError
from starterbus.core.model import Kind
from starterbus.core.registry import get_profile
from starterbus.core.simulator import ManualClock, SimulatedStarter
from starterbus.fleet.crosscheck import crosscheck
from starterbus.testing import wait_until
from starterbus.transports.modbus.master.mbap import HEADER, HEADER_LENGTH, MbapEngine, encode_adu
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator
from starterbus.transports.modbus.simulator.tcp import ModbusTcpSimulator
from starterbus.transports.modbus.transport.tcp import GATEWAYS


@pytest.fixture
def gateway() -> Iterator[ModbusTcpSimulator]:
    starters = {
        2: SimulatedStarter(get_profile("jjr5000"), ManualClock(0.0), load=0.5),
        3: SimulatedStarter(get_profile("ssd1"), ManualClock(0.0)),
    }
    with ModbusTcpSimulator(starters) as sim:
        yield sim


def test_units_behind_one_gateway_share_one_connection(gateway: ModbusTcpSimulator) -> None:
    jjr, ssd = gateway.starters[2], gateway.starters[3]
    with open_device(gateway.url(2), "jjr5000") as a, open_device(gateway.url(3), "ssd1") as b:
        assert GATEWAYS.users(("modbus-tcp", *gateway.address)) == 2
        assert wait_until(lambda: gateway.connections == 1)  # counted by the simulator's accept thread
        assert a.read("ramp_time")["ramp_time"].raw == jjr.params["ramp_time"]
        assert b.read("ramp_time")["ramp_time"].raw == ssd.params["ramp_time"]
        assert a.write("ramp_time", 33).ok and jjr.params["ramp_time"] == 33
        assert ssd.params["ramp_time"] != 33
        assert a.start().ok and a.status().starting
        poll = b.transport.poll([b.profile.point("ramp_time")], True)
        assert poll.status is not None and poll.readings[0].raw == ssd.params["ramp_time"]
        counters = b.transport.counters()
        assert counters is not None
        assert counters.transactions >= 2 and counters.requests == counters.transactions and not counters.errors
    assert GATEWAYS.users(("modbus-tcp", *gateway.address)) == 0


def test_a_device_refusal_reads_as_its_manual_says(gateway: ModbusTcpSimulator) -> None:
    gateway.starters[2].params["parameter_modify"] = 0
    with open_device(gateway.url(2), "jjr5000") as device, pytest.raises(RemoteDeviceError) as info:
        device.send_write(device.profile.point("ramp_time"), 20)
    assert info.value.code == 4 and info.value.meaning.startswith("parameter modification forbidden")
    assert info.value.protocol == "modbus-tcp"


def test_the_gateway_s_target_failed_is_no_answer_not_a_refusal(gateway: ModbusTcpSimulator) -> None:
    """Exception 0x0B: the device behind the gateway is silent. A TimeoutError (the fleet marks it offline and
    probes it), after the policy's attempts; never a RemoteDeviceError."""
    with open_device(gateway.url(7, retries=1, timeout=0.5), "jjr5000") as device:
        with pytest.raises(TimeoutError, match=r"unreachable: unit 7, exception 0x0B.*attempt 2 of 2"):
            device.status()
        counters = device.transport.counters()
        assert counters is not None and counters.timeouts == 1


def test_a_stale_answer_is_never_a_value(gateway: ModbusTcpSimulator) -> None:
    """The gateway answers the second request with the first one's transaction id (and another value): the
    client drops it and times out; the stale answer's value never comes out."""
    seen: list[int] = []

    def answer_with_the_previous_id(transaction: int, unit: int, pdu: bytes) -> bytes | None:
        seen.append(transaction)
        if len(seen) == 2:
            return encode_adu(seen[0], unit, bytes((0x03, 2, 0x12, 0x34)))  # 0x1234: never a ramp time
        return None

    gateway.answer_hook = answer_with_the_previous_id
    with open_device(gateway.url(2, retries=0, timeout=0.3), "jjr5000") as device:
        assert device.read("ramp_time")["ramp_time"].raw == 10
        with pytest.raises(TimeoutError, match="no answer from unit 2"):
            device.read("ramp_time")
        gateway.answer_hook = None
        assert device.read("ramp_time")["ramp_time"].raw == 10  # the next transaction is served as usual
        gateway_connection = device.transport._gateway  # type: ignore[attr-defined]
        assert gateway_connection is not None and gateway_connection.stale == 1
    assert seen[0] != seen[1]


def test_the_engine_matches_answers_to_waiting_transactions_only() -> None:
    engine = MbapEngine(first_id=0xFFFF)
    first, adu1 = engine.request(2, b"\x03\x01\x01\x00\x01")
    second, _ = engine.request(2, b"\x03\x01\x01\x00\x01")
    assert (first, second) == (0xFFFF, 0) and adu1[:HEADER_LENGTH] == HEADER.pack(0xFFFF, 0, 6, 2)
    engine.forget(first)  # given up: its answer is stale
    answers = engine.feed(encode_adu(first, 2, b"\x03\x02\x00\x0a") + encode_adu(second, 2, b"\x03\x02\x00\x0b")[:9])
    assert answers == [] and engine.stale == 1
    (answer,) = engine.feed(encode_adu(second, 2, b"\x03\x02\x00\x0b")[9:])
    assert (answer.transaction, answer.pdu) == (second, b"\x03\x02\x00\x0b")
    assert engine.feed(encode_adu(second, 2, b"\x03\x02\x00\x0b")) == [] and engine.stale == 2  # a duplicate


def test_outstanding_requests_go_out_before_the_first_answer() -> None:
    """outstanding=2: the second request of a poll is on the wire before the first is answered (a peer that
    answers only once it holds two requests would otherwise time the poll out)."""
    profile = get_profile("jjr8000")  # one register per FC03: a status poll is four requests
    starter = SimulatedStarter(profile, ManualClock(0.0), load=0.5)
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    most = [0]

    def serve() -> None:
        conn, _ = server.accept()
        with conn:
            buffer, pending = b"", []
            while True:
                data = conn.recv(4096)
                if not data:
                    return
                buffer += data
                while len(buffer) >= HEADER_LENGTH and len(buffer) >= _adu_length(buffer):
                    pending.append(buffer[: _adu_length(buffer)])
                    buffer = buffer[_adu_length(buffer) :]
                if len(pending) < 2:
                    continue  # answer nothing until two requests are here
                most[0] = max(most[0], len(pending))
                for adu in pending:
                    transaction, _, _, unit = HEADER.unpack_from(adu)
                    address = int.from_bytes(adu[8:10], "big")
                    value = starter.read(starter.point_at("modbus", Kind.MEASUREMENT, address))
                    conn.sendall(encode_adu(transaction, unit, bytes((0x03, 2)) + value.to_bytes(2, "big")))
                pending = []

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        url = f"modbus-tcp://127.0.0.1:{port}?unit=2&outstanding=2&timeout=2&retries=0"
        with open_device(url, profile) as device:
            result = device.transport.poll([], True)
        assert result.status is not None and not result.status.fault and most[0] == 2
    finally:
        server.close()
        thread.join(5)


def _adu_length(buffer: bytes) -> int:
    return HEADER_LENGTH - 1 + int(HEADER.unpack_from(buffer)[2])


def test_a_second_device_asking_other_connection_settings_is_refused(gateway: ModbusTcpSimulator) -> None:
    other = open_device(gateway.url(3, outstanding=4), "ssd1")
    with open_device(gateway.url(2), "jjr5000"), pytest.raises(ConfigurationError, match="one connection has one"):
        other.open()


def test_reconnects_after_the_gateway_restarts_and_backs_off_while_it_is_down() -> None:
    starter = SimulatedStarter(get_profile("ssd1"), ManualClock(0.0))
    sim = ModbusTcpSimulator({3: starter}).start()
    host, port = sim.address
    with open_device(sim.url(3, retries=0), "ssd1") as device:
        assert device.read("ramp_time")
        connection = device.transport._gateway  # type: ignore[attr-defined]
        assert connection is not None
        sim.close()
        assert wait_until(lambda: not connection.check())  # the connection saw the gateway close it
        with pytest.raises(TransportError, match="cannot connect"):
            device.read("ramp_time")
        with pytest.raises(TransportError, match="reconnecting in"):  # no connection attempt before the backoff
            device.read("ramp_time")
        with ModbusTcpSimulator({3: starter}, host, port):
            assert wait_until(lambda: _reads(device))
        assert connection.connects == 2


def _reads(device: object) -> bool:
    try:
        device.read("ramp_time")  # type: ignore[attr-defined]
    except TransportError:
        return False
    return True


def test_crosscheck_rtu_and_tcp_on_one_simulated_device() -> None:
    profile = get_profile("jjr5000")
    starter = SimulatedStarter(profile, ManualClock(0.0), load=0.5)
    starter.start()
    with ModbusTcpSimulator({2: starter}) as tcp, ModbusRtuSimulator({2: starter}, pty=True) as rtu:
        report = crosscheck([tcp.url(2), rtu.client_urls()[2]], profile)
    assert report.ok, [row.what for row in report.rows if row.agree is False] + [p.error for p in report.paths]
    assert any(row.agree for row in report.rows)


@pytest.fixture
def pymodbus_peer() -> Iterator[tuple[int, SimulatedStarter]]:
    """pymodbus's own TCP server (unit 2) holding the registers of a simulated JJR5000: an independent peer."""
    profile = get_profile("jjr5000")
    starter = SimulatedStarter(profile, ManualClock(0.0))
    values = [0] * 0x172
    for point in profile.points.values():
        values[point.address_for("modbus")] = starter.read(point)
    ready = threading.Event()
    ports: list[int] = []
    stops: list[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = []

    async def serve() -> None:
        device = SimDevice(id=2, simdata=[SimData(0, values=values, datatype=DataType.REGISTERS)])
        server = ModbusTcpServer(device, address=("127.0.0.1", 0))
        await server.serve_forever(background=True)
        listener = server.transport
        assert isinstance(listener, asyncio.Server), listener
        ports.append(listener.sockets[0].getsockname()[1])
        stop = asyncio.Event()
        stops.append((asyncio.get_running_loop(), stop))
        ready.set()
        await stop.wait()
        await server.shutdown()  # type: ignore[no-untyped-call]

    thread = threading.Thread(target=lambda: asyncio.run(serve()), daemon=True)
    thread.start()
    assert ready.wait(5)
    yield ports[0], starter
    loop, stop = stops[0]
    loop.call_soon_threadsafe(stop.set)
    thread.join(5)


def test_against_pymodbus_s_tcp_server(pymodbus_peer: tuple[int, SimulatedStarter]) -> None:
    port, starter = pymodbus_peer
    profile = starter.profile
    url = f"modbus-tcp://127.0.0.1:{port}?unit=2&timeout=2"
    with open_device(url, profile) as device:
        keys = [p.key for p in profile.parameters]
        values = device.read(*keys)
        assert {k: v.raw for k, v in values.items()} == {k: starter.params[k] for k in keys}
        assert not device.status().fault
        assert device.write("ramp_time", 42).ok  # FC06 echoed by pymodbus, read back by us
    other = ModbusTcpClient("127.0.0.1", port=port)
    try:
        assert other.read_holding_registers(0x0101, count=1, device_id=2).registers == [42]
    finally:
        other.close()  # type: ignore[no-untyped-call]
