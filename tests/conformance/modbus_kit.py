"""The conformance kit's hooks for Modbus RTU (the reference transport): several units on one pseudo-terminal, the
fault hook on :attr:`ModbusRtuSimulator.fault_hook`, the slave's refusal codes, the model's unit range and
speeds. Used by the built-in transport's kit run and by the mutant test (``test_kit_catches_mutants.py``).
:class:`ModbusHooks` (the faults and the refusal codes) serves the Modbus TCP kit run too."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping, Sequence

from starterbus.core.errors import Refusal
from starterbus.core.profile import Profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.testing import TransportConformance
from starterbus.testing.faults import DeviceTap, Fault
from starterbus.tests.conformance.served import Served
from starterbus.transports.modbus.codec.frames import AnyRequest
from starterbus.transports.modbus.settings import modbus_settings
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator, SlaveFault
from starterbus.transports.modbus.simulator.tcp import ModbusTcpSimulator
from starterbus.transports.modbus.slave import refusal_code

BUSY = 0x06  # Modbus exception "server device busy"
TARGET_FAILED = 0x0B  # a gateway's "target device failed to respond"
UNIT = 2


def slave_fault(fault: Fault | None, delay: float) -> SlaveFault | None:
    if fault is None:
        return None
    return {
        Fault.SILENT: SlaveFault(answer=False),
        Fault.SLOW: SlaveFault(delay=delay),
        Fault.LATE: SlaveFault(delay=delay),
        Fault.DUPLICATE: SlaveFault(copies=2),
        Fault.BUSY: SlaveFault(exception=BUSY),
        Fault.UNREACHABLE: SlaveFault(exception=TARGET_FAILED),
    }[fault]


class ModbusHooks(Served[ModbusRtuSimulator | ModbusTcpSimulator]):
    """The kit's hooks every Modbus simulator offers, RTU or TCP: the fault hook of the simulator that ``serve()``
    noted for each starter (:meth:`note_served`), and the slave's refusal codes."""

    @contextlib.contextmanager
    def faults(self, starter: SimulatedStarter) -> Iterator[DeviceTap]:
        sim, unit = self.served_by(starter)
        tap = DeviceTap()

        def hook(request: AnyRequest) -> SlaveFault | None:
            if request.unit != unit:
                return None
            return slave_fault(*tap.record(self.frame_text(request)))

        sim.fault_hook = hook
        try:
            yield tap
        finally:
            sim.fault_hook = None

    @staticmethod
    def frame_text(request: AnyRequest) -> str:
        """How the tap records a request that reached the device: as the transport's previews show it (RTU: the
        frame)."""
        return request.encode().hex(" ").upper()

    def refusal_code(self, profile: Profile, reason: Refusal) -> int | None:
        return int(refusal_code(profile, reason))


class ModbusRtuKit(ModbusHooks, TransportConformance):
    transport = "modbus-rtu"
    model = "jjr5000"
    url_timeout = "timeout"
    url_retries = "retries"
    merges_requests = True

    @contextlib.contextmanager
    def serve(self, starter: SimulatedStarter) -> Iterator[str]:
        with ModbusRtuSimulator({UNIT: starter}, pty=True) as sim:
            self.note_served(starter, sim, UNIT)
            yield sim.client_urls()[UNIT] + "&timeout=0.5"

    @contextlib.contextmanager
    def serve_units(self, starters: Sequence[SimulatedStarter]) -> Iterator[list[str]]:
        units = {UNIT + 5 * i: starter for i, starter in enumerate(starters)}
        with ModbusRtuSimulator(units, pty=True) as sim:
            urls = sim.client_urls()
            yield [urls[unit] + "&timeout=0.5" for unit in units]

    def invalid_url_values(self, profile: Profile) -> Mapping[str, Sequence[str]]:
        settings = modbus_settings(profile)
        speeds = [str(rate) for rate in (1200, 2400, 4800, 9600, 19200, 38400) if rate not in settings.baudrates]
        return {"unit": (str(settings.unit_ids[1] + 1), "256"), "baudrate": speeds[:1] if settings.baudrates else ()}
