"""Modbus TCP buses on the fleet's multiplexer (issue 29 steps 2 and 4): their polls are tasks advanced in the
scheduler's own thread (``starterbus-io``), which runs their connections too; no bus thread and no connection
thread; a unit the gateway cannot reach (0x0B) is offline without holding up the others."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.poller import FleetPoller
from starterbus.tests.fleet.conftest import Samples
from starterbus.transports.modbus.simulator.tcp import ModbusTcpSimulator


@pytest.fixture
def gateways() -> Iterator[list[ModbusTcpSimulator]]:
    sims: list[ModbusTcpSimulator] = []
    try:
        for _ in range(2):
            starters = {unit: SimulatedStarter(get_profile("jjr5000")) for unit in (1, 2)}
            sims.append(ModbusTcpSimulator(starters).start())
        yield sims
    finally:
        for sim in sims:
            sim.close()


def test_tcp_buses_are_polled_by_the_multiplexer_alone(gateways: list[ModbusTcpSimulator]) -> None:
    text = "[poll]\nperiod = 0.001\nmax_backoff = 0.2\n"
    for n, sim in enumerate(gateways):
        host, port = sim.address
        text += f'[[bus]]\nname = "gw{n}"\nurl = "modbus-tcp://{host}:{port}?timeout=0.3&retries=0"\n'
        for unit in (1, 2, 7):  # unit 7: nothing behind the gateway (0x0B)
            text += (
                f'[[bus.device]]\nname = "g{n}u{unit}"\nmodel = "jjr5000"\naddress = {unit}\n'
                'parameters = ["current_limit"]\n'
            )
    for n, sim in enumerate(gateways):
        for unit, starter in sim.starters.items():
            starter.params["current_limit"] = 200 + 10 * n + unit
    samples = Samples()
    before = {t.name for t in threading.enumerate()}
    threads: list[set[str]] = []
    samples.hooks.append(lambda _: threads.append({t.name for t in threading.enumerate()}))
    poller = FleetPoller(parse_fleet(text), samples, rounds=2)
    assert poller.mux is not None
    poller.start()
    poller.join(30.0)
    assert not poller.running
    assert set(samples.threads) == {"starterbus-io"}
    assert all(w.thread.ident is None for w in poller.workers), "no bus got a thread of its own"
    simulators = ("modbus-tcp client ", "modbus-tcp server ")  # the gateways' own threads
    extra = {name for seen in threads for name in seen - before if not name.startswith(simulators)}
    pool = {name for name in extra if name.startswith(("jobs-gw", "fleet-jobs"))}  # the fleet's pool opening devices
    assert extra - pool == {"starterbus-io"}, extra
    for n in range(2):
        for unit in (1, 2):
            polls = samples.of(f"g{n}u{unit}")
            assert len(polls) == 2 and all(p.online and p.error is None for p in polls)
            assert all(p.values["current_limit"].raw == 200 + 10 * n + unit for p in polls)
        offline = samples.of(f"g{n}u7")
        assert offline and not offline[0].online and "unreachable: unit 7, exception 0x0B" in str(offline[0].error)
