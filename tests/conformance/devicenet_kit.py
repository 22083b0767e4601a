"""The conformance kit's hooks for DeviceNet: the frames each simulated node gets (:attr:`DeviceNetSimulator.received`),
as the previews write them (candump form), a poll command only when its data changes (the master polls every
cycle). No fault acts: the kit's fault tests read parameters, which DeviceNet does not carry; the hook serves the
checks of previews (what a command sends) and of the poll plan.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from starterbus.core.simulator import SimulatedStarter
from starterbus.testing.faults import DeviceTap, Fault
from starterbus.tests.conformance.served import Served
from starterbus.transports.devicenet.codec.ids import poll_command_id
from starterbus.transports.devicenet.simulator import DeviceNetSimulator

NO_PARAMETERS = "DeviceNet carries no parameters, which the kit's fault tests read"
#: the simulated nodes' explicit connection's expected packet rate (ms): no keep-alive traffic within a test
QUIET_EPR_MS = 60000


class DeviceNetHooks(Served[DeviceNetSimulator]):
    """The kit's hooks of a node on a simulated bus: ``serve_units()`` notes each (:meth:`note_served`)."""

    @contextlib.contextmanager
    def faults(self, starter: SimulatedStarter) -> Iterator[DeviceTap]:
        sim, mac = self.served_by(starter)
        tap = DeviceTap(dict.fromkeys(Fault, NO_PARAMETERS))
        poll_id, last = poll_command_id(mac), [""]

        def received(node: int, can_id: int, data: bytes) -> None:
            text = f"{can_id:03X}#{data.hex().upper()}"
            if node == mac and (can_id != poll_id or text != last[0]):
                last[0] = text
                tap.record(text)

        sim.received = received
        try:
            yield tap
        finally:
            sim.received = None
