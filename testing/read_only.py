"""The kit's "a read never actuates" check: every read-only operation against a running simulated starter.

The starter is started through the simulator (``starter.start()``: the keypad, the terminals, or another master
that owns the network) and brought up to speed, so currents are not zero. Then the device is opened and every
read-only operation a user can reach runs against it: open and close, the status, every measurement and
parameter, identify, the poller's paths (``poll``, ``start_poll`` tasks, a probe, one round of the fleet
poller), ``plan``/``counters``/``describe``, dry-run previews of every write and command, a cross-check, a
backup, and a second connection opened while the first is open. The check fails if the motor's state changed,
a parameter changed, or any control output reached the starter (:attr:`SimulatedStarter.control_writes`; what
counts is documented in :mod:`starterbus.core.control_log`), naming the operation during which each was seen.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from starterbus.core.control_log import ControlWrite
from starterbus.core.device import Device, open_device
from starterbus.core.errors import ConfigurationError, UnsupportedOperationError
from starterbus.core.model import Kind, PointDef
from starterbus.core.polling import run_task
from starterbus.core.profile import Profile
from starterbus.core.simulator import ManualClock, Phase, SimulatedStarter
from starterbus.core.status import Command
from starterbus.core.transport import Capability

FLEET_ROUND_TIMEOUT = 30.0  # seconds for one round of the fleet poller (a failing device is probed, not hung on)


def run_motor(starter: SimulatedStarter, timeout: float = 60.0) -> None:
    """Start the motor as the keypad would and bring it to RUNNING (a manual clock is advanced; a real one is
    waited on)."""
    if not starter.start("started from the keypad (conformance kit)"):
        raise AssertionError(f"the simulated starter did not start from {starter.phase.value} (mains off?)")
    clock = starter.clock
    deadline = time.monotonic() + timeout
    while starter.phase is not Phase.RUNNING and time.monotonic() < deadline:
        if isinstance(clock, ManualClock):
            clock.advance(1.0)
        else:
            time.sleep(0.05)
    if starter.phase is not Phase.RUNNING or starter.current() <= 0:
        raise AssertionError(f"the simulated motor did not reach running: {starter.phase.value}")


class Watch:
    """Runs operations one by one and notes the control outputs the starter received while each ran."""

    def __init__(self, starter: SimulatedStarter) -> None:
        self.starter = starter
        self.seen: list[tuple[str, ControlWrite]] = []
        self.ran: list[str] = []

    def __call__(self, name: str, operation: Callable[[], object]) -> None:
        mark = self.starter.control_writes_total
        try:
            operation()
        except UnsupportedOperationError:
            pass  # not offered by this transport (or this point): nothing sent, by the template's rule
        finally:
            self.ran.append(name)
            self.seen += [(name, record) for record in self.starter.control_writes_since(mark)]


def readable(device: Device, kind: Kind) -> list[PointDef]:
    """Read the points of ``kind`` the device offers: all at once, or (where some are refused) one by one;
    returns those it read."""
    needed = Capability.READ_PARAMETERS if kind is Kind.PARAMETER else Capability.READ_MEASUREMENTS
    if needed not in device.capabilities:
        return []
    points = list(device.profile.parameters if kind is Kind.PARAMETER else device.profile.measurements)
    try:
        device.read(*points)
        return points
    except UnsupportedOperationError:
        pass
    found = []
    for point in points:
        try:
            device.read(point)
        except UnsupportedOperationError:
            continue
        found.append(point)
    return found


def previews(device: Device) -> None:
    """Every dry run: a write of each writable parameter (its lowest value) and each command."""
    transport = device.transport
    for point in device.profile.parameters:
        if point.writable:
            try:
                transport.preview_write(point, point.raw_min)
            except UnsupportedOperationError:
                pass
    for command in Command:
        try:
            transport.preview_command(command)
        except UnsupportedOperationError:
            pass


def poller_paths(device: Device, points: Sequence[PointDef]) -> list[tuple[str, Callable[[], object]]]:
    """What a poller asks of a transport: plan, poll, a poll task driven to its end, a probe, the counters."""
    transport = device.transport
    status = Capability.STATUS in device.capabilities
    if not points and not status:
        return []

    def task() -> object:
        started = transport.start_poll(points, status)
        return None if started is None else run_task(started, time.monotonic)

    def probe() -> object:
        with transport.probe_policy(1.0):
            return transport.poll(points, status)

    return [
        ("plan, counters, describe", lambda: (transport.plan(points, status), transport.counters(), device.describe())),
        ("poll", lambda: transport.poll(points, status)),
        ("start_poll task", task),
        ("probe (poll under probe_policy)", probe),
    ]


def fleet_round(url: str, profile: Profile) -> None:
    """One round of the fleet poller (status and the phase currents) on its own connection."""
    from starterbus.fleet.config import build_fleet
    from starterbus.fleet.poller import FleetPoller
    from starterbus.fleet.sample import Sample

    config = build_fleet(
        {"bus": [{"name": "kit", "url": url, "device": [{"name": "dut", "model": profile.name}]}]}, "<kit fleet>"
    )
    samples: list[Sample] = []
    poller = FleetPoller(config, samples.append, rounds=1).start()
    try:
        poller.join(FLEET_ROUND_TIMEOUT)
    finally:
        poller.stop()
    if not samples:
        raise AssertionError(f"the fleet poller gave no sample of {url} within {FLEET_ROUND_TIMEOUT:g} s")


def crosscheck_alone(url: str, profile: Profile) -> None:
    from starterbus.fleet.crosscheck import crosscheck

    crosscheck([url], profile)


def backup(device: Device) -> None:
    from starterbus.ops.backup import take_backup

    take_backup(device)


def second_connection(url: str, profile: Profile) -> None:
    """Another connection to the same device, used while the first is open (a transport may refuse it with a
    ConfigurationError, as a DeviceNet master refuses a MAC it has open; it must still send nothing)."""
    other = open_device(url, profile)
    try:
        other.open()
    except ConfigurationError:
        return
    with other:
        if Capability.STATUS in other.capabilities:
            other.status()
        elif other.profile.measurements:
            other.read(other.profile.measurements[0])


def check_reads_never_actuate(url: str, profile: Profile, starter: SimulatedStarter) -> None:
    """The check itself (:meth:`TransportConformance.test_reads_never_actuate`); AssertionError on failure."""
    run_motor(starter)
    before = (starter.phase, dict(starter.params))
    watch = Watch(starter)
    device = open_device(url, profile)
    watch("open", device.open)
    try:
        if Capability.STATUS in device.capabilities:
            watch("status", device.status)
        measurements: list[PointDef] = []
        parameters: list[PointDef] = []
        watch("read every measurement", lambda: measurements.extend(readable(device, Kind.MEASUREMENT)))
        watch("read every parameter", lambda: parameters.extend(readable(device, Kind.PARAMETER)))
        watch("identify", device.transport.identify)
        for name, operation in poller_paths(device, measurements):
            watch(name, operation)
        watch("previews (dry run of every write and command)", lambda: previews(device))
        watch("second connection while the first is open", lambda: second_connection(url, profile))
        if parameters:
            watch("backup", lambda: backup(device))
        if Capability.STATUS in device.capabilities:
            watch("status (last)", device.status)
    finally:
        watch("close", device.close)
    # the commands that open their own connections, as a separate process would (one connection at a time)
    watch("crosscheck", lambda: crosscheck_alone(url, profile))
    watch("one round of the fleet poller", lambda: fleet_round(url, profile))
    transport = device.transport.name
    if watch.seen:
        lines = [f"  seen during {name}: {record.describe()}" for name, record in watch.seen]
        raise AssertionError(
            f"read-only operations of {transport} sent control outputs to the running "
            f"{profile.display_name}:\n" + "\n".join(lines)
        )
    after = (starter.phase, dict(starter.params))
    if after[0] is not before[0]:
        raise AssertionError(
            f"read-only operations of {transport} changed the motor's state: {before[0].value} -> {after[0].value} "
            f"(operations: {', '.join(watch.ran)})"
        )
    changed = sorted(k for k in before[1] if before[1][k] != after[1][k])
    if changed:
        raise AssertionError(f"read-only operations of {transport} changed parameters: {', '.join(changed)}")
