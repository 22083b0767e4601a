"""The three built-in transports pass the conformance kit that third-party plugins use."""

from __future__ import annotations

import contextlib
import itertools
import os
from collections.abc import Iterator, Sequence

from starterbus.core.simulator import SimulatedStarter
from starterbus.testing import TransportConformance
from starterbus.tests.conformance.devicenet_kit import QUIET_EPR_MS, DeviceNetHooks
from starterbus.tests.conformance.modbus_kit import ModbusHooks, ModbusRtuKit
from starterbus.tests.conformance.pkw_kit import CYCLE, PkwHooks
from starterbus.transports.devicenet.simulator import DeviceNetSimulator
from starterbus.transports.modbus.codec.messages import AnyRequest
from starterbus.transports.modbus.simulator.tcp import ModbusTcpSimulator
from starterbus.transports.modbus.transport.tcp import adu_text
from starterbus.transports.profibus_pkw.simulator import ProfibusGatewaySimulator

_channels = itertools.count()


class TestModbusRtu(ModbusRtuKit):
    """The reference transport, with every hook of the kit (several units, faults, refusal codes)."""


class TestModbusRtuJjr8000(TestModbusRtu):
    model = "jjr8000"
    merges_requests = False  # one register per FC03 (the manual's limit)


class TestProfibusPpo1(PkwHooks, TransportConformance):
    """PKW through the simulated gateway, with the faults of its station (``pkw_kit``)."""

    transport = "profibus-pkw"
    model = "jjr8000"
    ppo = 1

    @contextlib.contextmanager
    def serve(self, starter: SimulatedStarter) -> Iterator[str]:
        with ProfibusGatewaySimulator(starter, ppo=self.ppo, cycle=CYCLE) as sim:
            self.note_served(starter, sim, 0)
            yield sim.client_urls()[1] + "&timeout=2"


class TestProfibusPpo3(TestProfibusPpo1):
    ppo = 3


class TestDeviceNet(DeviceNetHooks, TransportConformance):
    """DeviceNet on a virtual CAN bus, with the frames each node gets (``devicenet_kit``)."""

    transport = "devicenet"
    model = "jjr8000"

    @contextlib.contextmanager
    def serve(self, starter: SimulatedStarter) -> Iterator[str]:
        with self.serve_units([starter]) as (url,):
            yield url

    @contextlib.contextmanager
    def serve_units(self, starters: Sequence[SimulatedStarter]) -> Iterator[list[str]]:
        channel = f"conformance-{os.getpid()}-{next(_channels)}"
        macs = [5 + 5 * i for i in range(len(starters))]
        with DeviceNetSimulator(("virtual", channel), dup_mac_wait=0.05) as sim:  # the nodes on one bus
            for starter, mac in zip(starters, macs, strict=True):
                sim.add_node(starter, mac, explicit_epr_ms=QUIET_EPR_MS)
                self.note_served(starter, sim, mac)
            yield [
                f"devicenet://virtual/{channel}?mac={mac}&assemblies=extended&dup_mac_wait=0.05&timeout=1"
                for mac in macs
            ]


class TestModbusTcp(ModbusHooks, TransportConformance):
    """Modbus TCP through the simulated gateway (the kit's cross-check compares it with RTU on one starter), with
    the faults of a device behind it and the slave's refusal codes."""

    transport = "modbus-tcp"
    model = "jjr5000"
    url_timeout = "timeout"
    url_retries = "retries"

    @contextlib.contextmanager
    def serve(self, starter: SimulatedStarter) -> Iterator[str]:
        with self.serve_units([starter]) as (url,):
            yield url

    @contextlib.contextmanager
    def serve_units(self, starters: Sequence[SimulatedStarter]) -> Iterator[list[str]]:
        units = {2 + 5 * i: starter for i, starter in enumerate(starters)}
        with ModbusTcpSimulator(units) as sim:  # the units behind one gateway: one connection serves them all
            for unit, starter in units.items():
                self.note_served(starter, sim, unit)
            yield [sim.url(unit, timeout=0.5) for unit in units]

    @staticmethod
    def frame_text(request: AnyRequest) -> str:
        return adu_text(request)  # the MBAP ADU, its transaction id "TT TT" as in the previews


class TestModbusTcpSsd1(TestModbusTcp):
    model = "ssd1"
