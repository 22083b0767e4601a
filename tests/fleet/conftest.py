"""The demo fleet, started once per test module that needs it (simulators on ptys, loopback and a virtual bus);
Modbus RTU lines of simulated starters on ptys and a sample collector for the multiplexer's tests."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator

import pytest

from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.fleet.config import FleetConfig, parse_fleet
from starterbus.fleet.demo import DemoFleet, start_demo_fleet
from starterbus.fleet.sample import Sample
from starterbus.testing import wait_until
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator


@pytest.fixture(scope="module")
def demo() -> Iterator[DemoFleet]:
    fleet = start_demo_fleet(period=0.2)
    try:
        yield fleet
    finally:
        fleet.close()


class Samples:
    """Collects a poller's samples (and the thread that emitted each); tests wait on them, never sleep.

    ``hooks`` run first, in the polling thread, as the poller's ``on_sample`` does."""

    def __init__(self) -> None:
        self.list: list[Sample] = []
        self.threads: list[str] = []
        self.hooks: list[Callable[[Sample], None]] = []
        self.lock = threading.Lock()

    def __call__(self, sample: Sample) -> None:
        for hook in self.hooks:
            hook(sample)
        with self.lock:
            self.list.append(sample)
            self.threads.append(threading.current_thread().name)

    def snapshot(self) -> list[Sample]:
        with self.lock:
            return list(self.list)

    def wait_for(self, predicate: Callable[[list[Sample]], bool], timeout: float = 20.0) -> None:
        """Until ``predicate`` holds for the samples so far (``wait_until`` over a snapshot)."""
        assert wait_until(lambda: predicate(self.snapshot()), timeout), [
            (s.device, s.online, s.probe, s.error) for s in self.snapshot()[-10:]
        ]

    def mark(self) -> int:
        with self.lock:
            return len(self.list)

    def of(self, device: str, since: int = 0) -> list[Sample]:
        with self.lock:
            return [s for s in self.list[since:] if s.device == device]


class Lines:
    """``count`` Modbus RTU lines on ptys at 19200 baud, units 1..3 (JJR5000) on each; bus ``lineN`` holds the
    devices ``bNuU`` (line N, unit U), each polling its current limit and phase A current."""

    def __init__(self, count: int) -> None:
        self.sims: list[ModbusRtuSimulator] = []
        try:
            for _ in range(count):
                starters = {unit: SimulatedStarter(get_profile("jjr5000")) for unit in (1, 2, 3)}
                self.sims.append(ModbusRtuSimulator(starters, pty=True, baudrate=19200).start())
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        for sim in self.sims:
            sim.close()

    def base(self, line: int) -> str:
        return self.sims[line].url(1).split("?")[0]

    def starter(self, device: str) -> SimulatedStarter:
        line, unit = device[1:].split("u")
        return self.sims[int(line)].starters[int(unit)]

    def fleet(
        self,
        query: str = "timeout=0.5",
        *,
        period: float = 0.001,
        buses: int | None = None,
        units: dict[int, tuple[int, ...]] | None = None,
        url_params: dict[int, str] | None = None,
        bus_keys: dict[int, str] | None = None,
    ) -> FleetConfig:
        """The first ``buses`` lines (all) as buses; by line: ``units`` other than 1, 2, 3, ``url_params`` more
        of its URL (``&io=pyserial``), ``bus_keys`` more keys of its table (``delay = 0.05``)."""
        text = f"[poll]\nperiod = {period}\nmax_backoff = 0.2\n"
        for n in range(len(self.sims) if buses is None else buses):
            url = f"{self.base(n)}?baudrate=19200&{query}{(url_params or {}).get(n, '')}"
            text += f'[[bus]]\nname = "line{n}"\nurl = "{url}"\n{(bus_keys or {}).get(n, "")}\n'
            for unit in (units or {}).get(n, (1, 2, 3)):
                text += (
                    f'[[bus.device]]\nname = "b{n}u{unit}"\nmodel = "jjr5000"\naddress = {unit}\n'
                    'measurements = ["phase_a_current"]\nparameters = ["current_limit"]\n'
                )
        return parse_fleet(text)


@pytest.fixture
def lines() -> Iterator[Lines]:
    made = Lines(3)
    try:
        yield made
    finally:
        made.close()


@pytest.fixture
def samples() -> Samples:
    return Samples()
