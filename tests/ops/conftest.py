"""Simulated starters on one Modbus RTU pty line for the operator workflows.

Units 2 and 3 are JJR5000 with different parameters (A at the profile's defaults but for control_source, as
every simulated starter is commissioned for the bus; B changed, with its parameter-modify lock ON), unit 4 an
SSD1, unit 5 a JJR8000 (parameters locked while running, uncertain scales). The starters run on a clock 20
times faster than the wall clock, so a 10 s ramp takes half a second.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

B_VALUES = {"current_limit": 400, "ramp_time": 20, "start_mode": 1, "parameter_modify": 0}


class FastClock:
    def __init__(self, factor: float = 20.0) -> None:
        self.origin = time.monotonic()
        self.factor = factor

    def __call__(self) -> float:
        return self.origin + (time.monotonic() - self.origin) * self.factor


class Line:
    def __init__(self) -> None:
        clock = FastClock()
        j5 = get_profile("jjr5000")
        self.starters = {
            2: SimulatedStarter(j5, clock),
            3: SimulatedStarter(j5, clock, values=B_VALUES),
            4: SimulatedStarter(get_profile("ssd1"), clock),
            5: SimulatedStarter(get_profile("jjr8000"), clock),
        }
        self.functions: list[int] = []
        self.sim = ModbusRtuSimulator(self.starters, pty=True, trace=self._trace).start()

    def _trace(self, kind: str, data: bytes) -> None:
        if kind == "rx" and len(data) >= 2:
            self.functions.append(data[1])

    def url(self, unit: int) -> str:
        return self.sim.client_urls()[unit]

    @property
    def port(self) -> str:
        return self.url(2).split("://", 1)[1].split("?", 1)[0]


@pytest.fixture
def line() -> Iterator[Line]:
    line = Line()
    try:
        yield line
    finally:
        line.sim.close()
