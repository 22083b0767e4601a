"""One Modbus TCP connection per ``HOST:PORT`` in the process, whatever reaches it: ``modbus-tcp`` devices and
Profibus PKW gateway stations share it (one accept at the server), its one setting is checked both ways, and a
refused transaction withdraws the rest of its batch for every user of the connection."""

from __future__ import annotations

import struct
from collections.abc import Iterator

import pytest

from starterbus.core.device import open_device
from starterbus.core.engine import Ticket, TicketState
from starterbus.core.errors import ConfigurationError, RemoteDeviceError, TransportError
from starterbus.core.registry import get_profile
from starterbus.core.simulator import ManualClock, SimulatedStarter
from starterbus.transports.modbus.codec.messages import ExceptionResponse, ReadRequest, ReadResponse, Response
from starterbus.transports.modbus.driver.mbap_driver import MbapDriver
from starterbus.transports.modbus.driver.tcp_line import MbapConnection, connection_key
from starterbus.transports.modbus.master.exchange import Exchange, TransactionPolicy
from starterbus.transports.modbus.master.mbap import encode_adu
from starterbus.transports.modbus.simulator.tcp import ModbusTcpSimulator
from starterbus.transports.modbus.transport.tcp import GATEWAYS
from starterbus.transports.profibus_pkw.codec.codes import Ppo
from starterbus.transports.profibus_pkw.driver.channels import GatewayChannel

STATION = 9  # the unit of the gateway's DP image: no starter answers it, the test's hook does
PLAIN = 7  # a unit whose registers hold their own addresses (the hook's too)
INPUTS = (0x1111, 0x2222, 0x3333, 0x4444)
OUT, INP = 0, 100


class DpImage:
    """The gateway's DP image at unit :data:`STATION` (FC16 writes the outputs, FC03 reads the inputs), answered by
    the simulator's hook; every request of any unit is logged as (unit, function code, address)."""

    def __init__(self) -> None:
        self.outputs = [0] * 4
        self.log: list[tuple[int, int, int]] = []
        self.refuse: tuple[int, int] | None = None  # (unit, address) answered with exception 02

    def __call__(self, transaction: int, unit: int, pdu: bytes) -> bytes | None:
        function, address = pdu[0], struct.unpack_from(">H", pdu, 1)[0]
        self.log.append((unit, function, address))
        if self.refuse == (unit, address):
            return encode_adu(transaction, unit, bytes((function | 0x80, 2)))
        if unit == PLAIN:
            return encode_adu(transaction, unit, bytes((3, 2)) + struct.pack(">H", address))
        if unit != STATION:
            return None
        if function == 0x10:
            count = struct.unpack_from(">H", pdu, 3)[0]
            self.outputs[address - OUT : address - OUT + count] = struct.unpack_from(f">{count}H", pdu, 6)
            return encode_adu(transaction, unit, pdu[:5])
        assert (function, address) == (0x03, INP)
        return encode_adu(transaction, unit, bytes((3, 8)) + struct.pack(">4H", *INPUTS))


@pytest.fixture
def server() -> Iterator[tuple[ModbusTcpSimulator, DpImage]]:
    image = DpImage()
    with ModbusTcpSimulator({2: SimulatedStarter(get_profile("jjr5000"), ManualClock(0.0))}) as sim:
        sim.answer_hook = image
        yield sim, image
    assert not GATEWAYS.leases(), f"connections left open: {GATEWAYS.leases()}"


def channel(sim: ModbusTcpSimulator) -> GatewayChannel:
    return GatewayChannel("127.0.0.1", sim.address[1], Ppo.PPO1, out=OUT, inp=INP, unit=STATION, timeout=1.0)


@pytest.mark.parametrize("device_first", [True, False])
def test_a_device_and_a_gateway_station_share_one_connection(
    server: tuple[ModbusTcpSimulator, DpImage], device_first: bool
) -> None:
    sim, image = server
    key = connection_key("127.0.0.1", sim.address[1])
    starter = sim.starters[2]
    station = None if device_first else channel(sim)
    with open_device(sim.url(2), "jjr5000") as device:
        station = station or channel(sim)
        try:
            assert GATEWAYS.users(key) == 2
            assert station.exchange([0x1234, None, 5, 6]) == INPUTS
            assert device.read("ramp_time")["ramp_time"].raw == starter.params["ramp_time"]
            assert station.exchange([0x1234, 7, None, None]) == INPUTS
            assert image.outputs == [0x1234, 7, 5, 6]
            assert sim.connections == 1  # one accept for both users
            units = {unit for unit, _, _ in image.log}
            assert units == {2, STATION}
        finally:
            if device_first:
                station.close()
        assert GATEWAYS.users(key) == (1 if device_first else 2)
    if not device_first:
        assert station.exchange([1, 2, 3, 4]) == INPUTS  # the device gone, the station keeps the connection
        assert sim.connections == 1
        station.close()
    assert GATEWAYS.users(key) == 0


def test_the_connections_one_setting_is_checked_both_ways(server: tuple[ModbusTcpSimulator, DpImage]) -> None:
    sim, _ = server
    key = connection_key("127.0.0.1", sim.address[1])
    with open_device(sim.url(2, outstanding=2), "jjr5000"):
        with pytest.raises(ConfigurationError, match=r"outstanding=2 \(modbus-tcp\): a gateway's stations need"):
            channel(sim)
        assert GATEWAYS.users(key) == 1
    station = channel(sim)  # the station's hold on its registers was let go when it was refused: taken again
    try:
        with (
            pytest.raises(ConfigurationError, match="outstanding: gateway 127.0.0.1:.* outstanding=1"),
            open_device(sim.url(2, outstanding=2), "jjr5000"),
        ):
            pass
        assert GATEWAYS.users(key) == 1
    finally:
        station.close()


@pytest.mark.parametrize("outstanding", [1, 3])
def test_a_refusal_withdraws_the_rest_of_its_batch(
    server: tuple[ModbusTcpSimulator, DpImage], outstanding: int
) -> None:
    """Three reads as one batch, the second refused: one at a time the third is never sent; with three on the wire
    (the simulator not answering the third) the call ends with the refusal, not waiting out the third's timeout."""
    sim, image = server
    image.refuse = (PLAIN, 20)
    hook = image

    def silent_third(transaction: int, unit: int, pdu: bytes) -> bytes | None:
        answer = hook(transaction, unit, pdu)
        return b"" if unit == PLAIN and pdu[1:3] == bytes((0, 30)) else answer

    sim.answer_hook = silent_third
    policy = TransactionPolicy(timeout=5.0, retries=0)
    reads = [Exchange(ReadRequest(PLAIN, address, 1), policy, 0.0) for address in (10, 20, 30)]
    connection = MbapConnection("127.0.0.1", sim.address[1], outstanding, 1.0)
    try:
        answers = connection.run_many(reads)
        assert answers[0] == ReadResponse(PLAIN, (10,)) and isinstance(answers[1], ExceptionResponse)
        assert len(answers) == 2
        assert isinstance(connection.run_many(reads[:1])[0], ReadResponse)  # the connection goes on
        # (the simulator takes a connection's requests in order: with this read answered, it has seen all before it)
        sent = [address for unit, _, address in image.log if unit == PLAIN]
        assert sent == ([10, 20, 10] if outstanding == 1 else [10, 20, 30, 10])
    finally:
        connection.close()


def test_a_poll_refused_on_the_way_reads_as_the_devices_refusal(server: tuple[ModbusTcpSimulator, DpImage]) -> None:
    sim, image = server
    with open_device(sim.url(2), "jjr5000") as device:
        points = [device.profile.point("ramp_time")]
        plan = device.transport.poll_plans.get(points, True)  # type: ignore[attr-defined]
        assert len(plan.requests) > 1
        image.refuse = (2, plan.requests[0][0])
        before = len(image.log)
        with pytest.raises(RemoteDeviceError, match="illegal data address|02"):
            device.transport.poll(points, True)
        assert len(image.log) - before == 1  # nothing after the refused request went out


def test_a_defect_under_a_batch_submitted_in_the_loop_fails_it_and_tells_it(monkeypatch: pytest.MonkeyPatch) -> None:
    """``submit_then``'s own step raising what no transport should (a defect): every ticket of the batch fails with a
    TransportError naming the connection and the defect, as the scheduler says a step's, and the batch is told."""
    driver = MbapDriver("127.0.0.1", 1, 1, 1.0)

    def broken(now: float, ready: bool) -> None:
        raise RuntimeError("boom")

    monkeypatch.setattr(driver, "step", broken)
    told: list[list[Ticket[Exchange, Response]]] = []
    policy = TransactionPolicy(timeout=1.0, retries=0)
    driver.submit_then(
        [Exchange(ReadRequest(PLAIN, address, 1), policy, 0.0) for address in (10, 20)], 0.0, told.append
    )
    (tickets,) = told
    assert [ticket.state for ticket in tickets] == [TicketState.FAILED, TicketState.FAILED]
    assert {str(ticket.error) for ticket in tickets} == {"gateway 127.0.0.1:1: RuntimeError: boom"}
    assert all(type(ticket.error) is TransportError for ticket in tickets)
    assert driver.crashes == 1 and driver.pending == 0
