"""A fleet polling a ``modbus-tcp`` device and a Profibus PKW station mapped on the same gateway ``HOST:PORT``: one
TCP connection for both buses, each device's own values, every poll in the scheduler's thread."""

from __future__ import annotations

import struct
import threading
from collections.abc import Iterator

import pytest

from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.poller import FleetPoller
from starterbus.tests.fleet.conftest import Samples
from starterbus.transports.modbus.master.mbap import encode_adu
from starterbus.transports.modbus.simulator.tcp import ModbusTcpSimulator
from starterbus.transports.profibus_pkw.codec.codes import Ppo
from starterbus.transports.profibus_pkw.slave import SimulatedDpSlave

STATION, OUT, INP = 9, 0, 100


class DpImage:
    """A gateway's DP image at unit :data:`STATION` over the simulator's hook: an FC16 sets the station's outputs,
    each FC03 of its inputs is one DP exchange with the simulated slave, an FC03 of its outputs reads them back (the
    other units answer as usual)."""

    def __init__(self, slave: SimulatedDpSlave) -> None:
        self.slave = slave
        self.outputs: list[int] = [0] * slave.ppo.words
        self.lock = threading.Lock()  # the simulator answers each connection in a thread of its own

    def __call__(self, transaction: int, unit: int, pdu: bytes) -> bytes | None:
        if unit != STATION:
            return None
        function, address, count = pdu[0], *struct.unpack_from(">HH", pdu, 1)
        with self.lock:
            if function == 0x10:
                self.outputs[address - OUT : address - OUT + count] = struct.unpack_from(f">{count}H", pdu, 6)
                return encode_adu(transaction, unit, pdu[:5])
            assert function == 0x03 and address in (OUT, INP) and count == len(self.outputs), pdu.hex()
            inputs = self.slave.exchange(self.outputs) if address == INP else tuple(self.outputs)
        return encode_adu(transaction, unit, bytes((3, 2 * count)) + struct.pack(f">{count}H", *inputs))


@pytest.fixture
def gateway() -> Iterator[tuple[ModbusTcpSimulator, SimulatedStarter, SimulatedStarter]]:
    plain, station = SimulatedStarter(get_profile("jjr5000")), SimulatedStarter(get_profile("jjr8000"))
    plain.params["current_limit"], station.params["current_limit"] = 321, 432
    with ModbusTcpSimulator({2: plain}) as sim:
        sim.answer_hook = DpImage(SimulatedDpSlave(station, Ppo.PPO1))
        yield sim, plain, station


def test_a_modbus_tcp_bus_and_a_gateway_station_share_the_connection(
    gateway: tuple[ModbusTcpSimulator, SimulatedStarter, SimulatedStarter],
) -> None:
    sim, plain, station = gateway
    host, port = sim.address
    text = (
        "[poll]\nperiod = 0.01\nmax_backoff = 0.2\n"
        f'[[bus]]\nname = "tcp"\nurl = "modbus-tcp://{host}:{port}?timeout=1"\n'
        '[[bus.device]]\nname = "plain"\nmodel = "jjr5000"\naddress = 2\nparameters = ["current_limit"]\n'
        f'[[bus]]\nname = "dp"\nurl = "profibus-pkw+gateway://{host}:{port}?ppo=1&out={OUT}&in={INP}'
        f'&unit={STATION}&cycle=0.01&timeout=1"\n'
        '[[bus.device]]\nname = "station"\nmodel = "jjr8000"\naddress = 2\nparameters = ["current_limit"]\n'
    )
    samples = Samples()
    poller = FleetPoller(parse_fleet(text), samples, rounds=3)
    poller.start()
    poller.join(60.0)
    assert not poller.running
    for name, starter in (("plain", plain), ("station", station)):
        polls = samples.of(name)
        assert len(polls) == 3 and all(p.online and p.error is None for p in polls), polls
        assert all(p.values["current_limit"].raw == starter.params["current_limit"] for p in polls)
    assert sim.connections == 1  # both buses on one connection
    assert set(samples.threads) == {"starterbus-io"}
    assert all(w.thread.ident is None for w in poller.workers), "no bus got a thread of its own"
