"""Issue 29's thread count: `poll` of a 16-line mixed fleet (Modbus RTU, Modbus TCP, Profibus PKW in process and
behind a Modbus TCP gateway, DeviceNet and, where the plugin is installed, CANopen) runs on the scheduler's one
thread, python-can's readers for buses without a descriptor and the fleet's small job pool (opening devices):
nothing per bus."""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator

from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.poller import FleetPoller
from starterbus.tests.fleet.conftest import Samples
from starterbus.transports.devicenet.simulator import DeviceNetSimulator
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator
from starterbus.transports.modbus.simulator.tcp import ModbusTcpSimulator
from starterbus.transports.profibus_pkw.driver.channels import attach_slave, detach_slave
from starterbus.transports.profibus_pkw.simulator import ProfibusGatewaySimulator

RTU_LINES = 10
POOL_MAX = 4  # fleet/jobs.py: the job pool's threads at most


def _bus(name: str, url: str, model: str, address: int) -> str:
    return (
        f'[[bus]]\nname = "{name}"\nurl = "{url}"\n'
        f'[[bus.device]]\nname = "{name}-dev"\nmodel = "{model}"\naddress = {address}\nmeasurements = []\n'
    )


@contextlib.contextmanager
def mixed_fleet() -> Iterator[tuple[str, list[str]]]:
    """The fleet file's text and its device names, every simulator running (their threads started here)."""
    tag = f"threads-{os.getpid()}"
    with contextlib.ExitStack() as stack:
        text, devices = "[poll]\nperiod = 0.02\nmax_backoff = 0.5\n", []
        for n in range(RTU_LINES):
            sim = stack.enter_context(ModbusRtuSimulator({1: SimulatedStarter(get_profile("jjr5000"))}, pty=True))
            pty = sim.client_urls()[1].split("://", 1)[1].split("?", 1)[0]
            text += _bus(f"rtu{n}", f"modbus-rtu://{pty}?timeout=0.3", "jjr5000", 1)
        for n in range(2):
            tcp = ModbusTcpSimulator({1: SimulatedStarter(get_profile("jjr5000"))}).start()
            stack.callback(tcp.close)
            host, port = tcp.address
            text += _bus(f"tcp{n}", f"modbus-tcp://{host}:{port}?timeout=0.3", "jjr5000", 1)
        name = f"{tag}-pkw0"
        attach_slave(name, SimulatedStarter(get_profile("jjr8000")))
        stack.callback(detach_slave, name)
        text += _bus("pkw0", f"profibus-pkw+sim://{name}?ppo=1&cycle=0.01", "jjr8000", 2)
        gateway = ProfibusGatewaySimulator(SimulatedStarter(get_profile("jjr8000")), port=0, ppo=1, cycle=0.002)
        stack.callback(gateway.start().close)
        text += _bus("pkw1", f"{gateway.url(0)}&cycle=0.01", "jjr8000", 2)
        dnet = stack.enter_context(DeviceNetSimulator(("virtual", f"{tag}-dnet"), dup_mac_wait=0.05))
        dnet.add_node(SimulatedStarter(get_profile("jjr8000")), 5)
        text += _bus("dnet", f"devicenet://virtual/{tag}-dnet?assemblies=extended&dup_mac_wait=0.05", "jjr8000", 5)
        try:
            from starterbus_canopen.simulator import CanopenSimulator
        except ImportError:  # the plugin is not installed: a 15-line fleet
            pass
        else:
            can = stack.enter_context(CanopenSimulator(("virtual", f"{tag}-can"), heartbeat_ms=0))
            can.add_node(SimulatedStarter(get_profile("example_canopen_starter")), 5)
            text += _bus("can", f"canopen://virtual/{tag}-can", "example_canopen_starter", 5)
        devices = [line.split('"')[1] for line in text.splitlines() if line.startswith("name = ") and "-dev" in line]
        yield text, devices


def test_a_mixed_fleet_polls_on_the_scheduler_with_nothing_per_bus() -> None:
    with mixed_fleet() as (text, devices):
        assert len(devices) >= 15
        before = {t.ident for t in threading.enumerate()}  # the simulators' own threads among them
        seen: dict[int, str] = {}

        def look(_: object) -> None:
            seen.update({t.ident: t.name for t in threading.enumerate() if t.ident not in before and t.ident})

        samples = Samples()
        samples.hooks.append(look)
        poller = FleetPoller(parse_fleet(text, "mixed.toml"), samples).start()
        try:
            samples.wait_for(lambda got: all(sum(s.device == d and s.online for s in got) >= 3 for d in devices), 60)
        finally:
            poller.stop()
        assert poller.failure is None
    names = sorted(seen.values())
    assert all(w.thread.ident is None for w in poller.workers), "a bus got a thread of its own"
    assert not [n for n in names if n.startswith(("bus-", "bus-mux", "devicenet-scanner", "profibus-pkw cycle"))]
    pool = [n for n in names if n.startswith(("jobs-", "fleet-jobs"))]
    readers = [n for n in names if n.startswith("can-reader")]
    assert names.count("starterbus-io") == 1, names
    assert len(pool) <= POOL_MAX and len(readers) <= 2, names  # a reader per virtual CAN bus: no descriptor
    # nothing else: the simulators' threads started before the poller; their per-connection threads are named
    others = [n for n in names if n not in pool + readers + ["starterbus-io"]]
    assert all(n.startswith(("modbus-tcp server", "modbus-tcp client")) for n in others), others
    assert len(samples.threads) and set(samples.threads) == {"starterbus-io"}, set(samples.threads)
