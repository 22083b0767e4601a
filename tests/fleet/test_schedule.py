"""The bus worker's schedule, driven by a ManualClock and a scripted transport (no I/O, no threads, no sleeps)."""

from __future__ import annotations

import contextlib
import random
from collections.abc import Iterator, Sequence

import pytest

from starterbus.core.device import Device
from starterbus.core.errors import TimeoutError
from starterbus.core.model import PointDef, Reading
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.simulator import ManualClock
from starterbus.core.transport import PollResult, TransportCounters
from starterbus.core.url import DeviceUrl
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.poller import BusWorker, DeviceRuntime, FleetPoller
from starterbus.fleet.probing import ProbeSettings
from starterbus.tests.stub_transport import StubTransport


class ScriptedTransport(StubTransport):
    """Answers (or not) after ``took`` seconds of the manual clock; records each poll's timeout and retries."""

    name = "scripted"

    def __init__(self, profile: Profile, clock: ManualClock, took: float) -> None:
        super().__init__(DeviceUrl.parse("scripted://line"), profile)
        self.clock = clock
        self.took = took
        self.alive = True
        self.timeout = 0.3
        self.retries = 2
        self.calls: list[tuple[float, int]] = []  # (timeout, retries) of each poll
        self._counters = TransportCounters()

    def _poll(self, points: Sequence[PointDef], status: bool) -> PollResult:
        self.calls.append((self.timeout, self.retries))
        attempts = 1 if self.alive else 1 + self.retries
        self.clock.advance(self.took if self.alive else attempts * self.timeout)
        self._counters.transactions += 1
        self._counters.requests += attempts
        if not self.alive:
            self._counters.timeouts += 1
            raise TimeoutError(f"no answer within {self.timeout:g} s")
        return PollResult(None, [Reading(p, 1) for p in points])

    @contextlib.contextmanager
    def probe_policy(self, timeout: float) -> Iterator[None]:
        normal = self.timeout, self.retries
        self.timeout, self.retries = min(timeout, self.timeout), 0
        try:
            yield
        finally:
            self.timeout, self.retries = normal

    def counters(self) -> TransportCounters:
        return self._counters


def worker(
    clock: ManualClock, share: float = 0.1, max_backoff: float = 30.0
) -> tuple[BusWorker, list[ScriptedTransport]]:
    config = parse_fleet(
        f"[poll]\nperiod = 0.2\nmax_backoff = {max_backoff}\n"
        '[[bus]]\nname = "rtu"\nurl = "modbus-rtu:///dev/null?baudrate=19200"\n'
        '[[bus.device]]\nname = "a"\nmodel = "jjr5000"\naddress = 1\n'
        '[[bus.device]]\nname = "b"\nmodel = "jjr5000"\naddress = 2\n'
    )
    poller = FleetPoller(config, clock=clock, probing=ProbeSettings(0.05, share), rng=random.Random(3))
    bus = poller.workers[0]
    profile = get_profile("jjr5000")
    transports = []
    for runtime in bus.devices:
        transport = ScriptedTransport(profile, clock, took=0.01)
        runtime.device = Device(transport, profile).open()
        transports.append(transport)
    return bus, transports


def online(runtime: DeviceRuntime) -> bool | None:
    return runtime.online  # read through a call: mypy narrowed the attribute at an earlier assert


def poll_at(bus: BusWorker, runtime: DeviceRuntime, due: float) -> None:
    runtime.next_due = due
    bus._poll(runtime)


def test_a_late_poll_keeps_the_grid() -> None:
    clock = ManualClock(100.0)
    bus, _ = worker(clock)
    runtime = bus.devices[0]
    poll_at(bus, runtime, 0.0)  # the worker queues every device at 0.0 at first
    assert runtime.next_due == pytest.approx(100.2), "the first poll starts a grid where it started"
    clock.now = 100.28  # started 0.08 s late (the line was busy)
    poll_at(bus, runtime, 100.2)
    assert runtime.next_due == pytest.approx(100.4), "the next slot of the grid, not 0.2 s after the late start"
    clock.now = 100.9  # more than a period late: a new grid from there
    poll_at(bus, runtime, 100.4)
    assert runtime.next_due == pytest.approx(101.1)


def test_an_offline_device_is_probed_with_one_short_attempt_and_backs_off() -> None:
    clock = ManualClock(100.0)
    bus, transports = worker(clock, share=1.0)
    runtime, transport = bus.devices[1], transports[1]
    transport.alive = False
    poll_at(bus, runtime, clock.now)
    assert transport.calls == [(0.3, 2)], "the poll that finds it gone uses the full policy"
    assert runtime.online is False and runtime.probes == 0
    gaps = []
    for _ in range(8):
        due = runtime.next_due
        gaps.append(due - clock.now)
        clock.now = due
        poll_at(bus, runtime, due)
    assert transport.calls[1:] == [(0.05, 0)] * 8, "probes: one attempt, the probe timeout"
    assert runtime.probes == 8 and bus.stats.probes == 8
    nominal = [min(0.2 * 2**n, 30.0) for n in range(8)]
    assert all(0.75 * n <= g <= n for g, n in zip(gaps, nominal, strict=True)), gaps
    transport.alive = True
    clock.now = runtime.next_due
    poll_at(bus, runtime, clock.now)
    assert online(runtime) and transport.calls[-1] == (0.05, 0), "it comes back with the probe it answers"
    clock.now = runtime.next_due
    poll_at(bus, runtime, clock.now)
    assert transport.calls[-1] == (0.3, 2), "and is polled normally again"


def test_probes_wait_for_the_line_s_probe_budget() -> None:
    clock = ManualClock(100.0)
    bus, transports = worker(clock, share=0.1, max_backoff=0.2)
    runtime, transport = bus.devices[1], transports[1]
    transport.alive = False
    poll_at(bus, runtime, clock.now)  # goes offline (0.9 s: not a probe, not charged to the probe budget)
    probing = 0.0
    start = clock.now
    for _ in range(40):
        due = runtime.next_due
        clock.now = max(clock.now, due)
        when = bus.start_time(due, runtime, clock.now)
        if when > clock.now:  # the worker would requeue it until then
            clock.now = when
            assert bus.start_time(due, runtime, clock.now) == due
        before = clock.now
        poll_at(bus, runtime, due)
        probing += clock.now - before
    assert runtime.probes == 40
    assert probing <= 0.1 * (clock.now - start) + 0.05 + 0.05 + 1e-9, "at most the share, a burst and one probe"
    assert bus.start_time(clock.now + 1.0, runtime, clock.now) == clock.now + 1.0, "a future slot is not moved"
    assert bus.start_time(clock.now, bus.devices[0], clock.now) == clock.now, "live devices never wait for it"
