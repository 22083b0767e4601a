"""The multiplexer keeps every bus going when one transport's task misbehaves (no I/O: tasks done at once)."""

from __future__ import annotations

from collections.abc import Sequence

from starterbus.core.device import Device
from starterbus.core.model import PointDef, Reading
from starterbus.core.polling import PollResult, PollTask
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.url import DeviceUrl
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.poller import FleetPoller, Sample
from starterbus.tests.stub_transport import StubTransport


class InstantTask(PollTask):
    """Done at its first advance: a result, or (``crash``) an exception no task may raise."""

    def __init__(self, points: Sequence[PointDef], crash: bool) -> None:
        self.points = points
        self.crash = crash
        self.cancelled = False

    def advance(self, now: float) -> None:
        if self.crash:
            raise RuntimeError("a defect in the plugin")
        self.done = True

    def result(self) -> PollResult:
        if self.cancelled:
            from starterbus.core.errors import TransportError

            raise TransportError("cancelled")
        return PollResult(None, [Reading(p, 7) for p in self.points])

    def cancel(self) -> None:
        if not self.done:
            self.cancelled = self.done = True


class TaskTransport(StubTransport):
    name = "tasks"

    def __init__(self, profile: Profile, crash: bool) -> None:
        super().__init__(DeviceUrl.parse("tasks://line"), profile)
        self.crash = crash
        self.tasks: list[InstantTask] = []

    def _start_poll(self, points: Sequence[PointDef], status: bool) -> PollTask | None:
        task = InstantTask(points, self.crash)
        self.tasks.append(task)
        return task


def test_a_task_that_raises_fails_its_poll_and_every_other_bus_goes_on() -> None:
    config = parse_fleet(
        "[poll]\nperiod = 0.01\n"
        '[[bus]]\nname = "bad"\nurl = "modbus-rtu:///dev/null?baudrate=19200"\n'
        '[[bus.device]]\nname = "a"\nmodel = "jjr5000"\naddress = 1\nmeasurements = ["phase_a_current"]\n'
        '[[bus]]\nname = "good"\nurl = "modbus-rtu:///dev/zero?baudrate=19200"\n'
        '[[bus.device]]\nname = "b"\nmodel = "jjr5000"\naddress = 1\nmeasurements = ["phase_a_current"]\n'
    )
    samples: list[Sample] = []
    poller = FleetPoller(config, samples.append, rounds=3)
    assert poller.mux is not None and len(poller.mux.buses) == 2, "both Modbus buses are multiplexed"
    profile = get_profile("jjr5000")
    transports = {}
    for worker in poller.workers:
        for runtime in worker.devices:
            transport = TaskTransport(profile, crash=worker.bus.name == "bad")
            runtime.device = Device(transport, profile).open()
            transports[worker.bus.name] = transport
    poller.start()
    poller.join(timeout=10)
    assert not poller.running
    bad = [s for s in samples if s.device == "a"]
    good = [s for s in samples if s.device == "b"]
    assert len(bad) == 3 and all(not s.online for s in bad)
    # offline at once; the device is then closed and reopened from its URL (here /dev/null, which fails)
    assert bad[0].error == "bad: the poll failed: RuntimeError: a defect in the plugin"
    assert [t.cancelled for t in transports["bad"].tasks] == [True], "the task that raised was cancelled"
    assert len(good) == 3 and all(s.online and s.error is None for s in good)
    assert all(s.values["phase_a_current"].raw == 7 for s in good)
