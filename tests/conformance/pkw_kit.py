"""The conformance kit's hooks for Profibus PKW behind the simulated Modbus TCP gateway: the requests are what the
master writes into the station's output area (:attr:`ProfibusGatewaySimulator.written`), as the previews show a
telegram, each time it changes; the faults act through the station's :attr:`SimulatedDpSlave.fault_hook` and the
gateway's :attr:`ProfibusGatewaySimulator.unreachable`.

What a PKW device can do wrong: a task's response lost (silent) or shown late (slow, late), and the gateway's
"target device failed to respond" (unreachable). A duplicated answer is not a fault here: a slave shows its
response in every cycle until the next task. Busy is not either: neither manual has a PKW error number for it.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from starterbus.core.simulator import SimulatedStarter
from starterbus.testing.faults import DeviceTap, Fault
from starterbus.tests.conformance.served import Served
from starterbus.transports.profibus_pkw.codec.telegram import hex_text
from starterbus.transports.profibus_pkw.simulator import ProfibusGatewaySimulator
from starterbus.transports.profibus_pkw.slave import PkwFault

#: the DP cycle of the simulated gateway (s)
CYCLE = 0.002
REPEATED = "a slave shows its response in every cycle until the next task: every answer is repeated"
NO_BUSY = "neither manual has a PKW error number for 'busy'"


def pkw_fault(fault: Fault | None, delay: float) -> PkwFault | None:
    if fault is Fault.SILENT:
        return PkwFault(answer=False)
    if fault in (Fault.SLOW, Fault.LATE):
        return PkwFault(delay=delay)
    return None  # unreachable: the gateway's; the others are not supported


def telegram_text(words: tuple[int, ...]) -> str:
    """An output telegram as the transport's previews write it."""
    return hex_text(b"".join(word.to_bytes(2, "big") for word in words))


class PkwHooks(Served[ProfibusGatewaySimulator]):
    """The kit's hooks of a station behind the simulated gateway: ``serve()`` notes it (:meth:`note_served`)."""

    url_timeout: str | None = "timeout"
    fixed_retries: int | None = 0  # a task is never sent again: its time limit covers the whole job
    slow_answer: float = 2.5  # longer than the default time limit of a job (2 s)

    @contextlib.contextmanager
    def faults(self, starter: SimulatedStarter) -> Iterator[DeviceTap]:
        sim, index = self.served_by(starter)
        slave = sim.slaves[index]
        tap = DeviceTap({Fault.DUPLICATE: REPEATED, Fault.BUSY: NO_BUSY})
        last: list[tuple[int, ...]] = []

        def written(k: int, words: tuple[int, ...]) -> None:
            """What the master writes, where it changes (the first write included: a telegram the image already
            held is still the master's)."""
            if k == index and (not last or words != last[-1]):
                last[:] = [words]
                tap.record(telegram_text(words))

        def hook(words: tuple[int, ...]) -> PkwFault | None:
            return pkw_fault(*tap.fault)

        slave.fault_hook = hook
        sim.written = written
        sim.unreachable = lambda k: k == index and tap.fault[0] is Fault.UNREACHABLE
        try:
            yield tap
        finally:
            slave.fault_hook = None
            sim.written = None
            sim.unreachable = None
