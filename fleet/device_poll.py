"""One poll of one device of a fleet's bus, blocking or as a poll task: opened, counted, its result turned into
the device's state, next time and sample (:class:`DevicePolls`, the base of the bus worker).

A device that stops answering is marked offline at once (its values are dropped, never shown as fresh); any error
leaves it offline with the error said. Each poll's wire counts are added to the bus's (:class:`LineStats`).
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field

from starterbus.core.device import Device, open_device
from starterbus.core.errors import StarterbusError, TimeoutError, TransportError
from starterbus.core.model import PointDef, Value
from starterbus.core.polling import PollResult
from starterbus.core.status import Status
from starterbus.core.transport import TransportCounters
from starterbus.fleet.config import BusConfig, DeviceConfig
from starterbus.fleet.line_stats import LineStats
from starterbus.fleet.plan import poll_points
from starterbus.fleet.poll_context import PollContext
from starterbus.fleet.probing import ProbeBudget, backoff
from starterbus.fleet.sample import Sample, polled

__all__ = ["Attempt", "DevicePolls", "DeviceRuntime"]


@dataclass
class DeviceRuntime:
    """What the poller knows about one device right now."""

    config: DeviceConfig
    device: Device | None = None
    online: bool | None = None  # None: not polled yet
    last_ok: float | None = None  # monotonic time of the last good poll
    last_sample: Sample | None = None
    errors: int = 0
    polls: int = 0
    failures_in_a_row: int = 0
    next_due: float = 0.0
    skipped: set[str] = field(default_factory=set)  # keys this transport cannot read, reported once
    unreadable: tuple[str, ...] = ()  # ``skipped``, sorted (each sample carries it)
    points: list[PointDef] | None = None  # what each poll reads, resolved once the device is open
    status: bool = False  # whether each poll reads the status
    slowest_request: float = 0.0  # longest time per request of a good poll, s (floor of the probe timeout)
    probes: int = 0
    slot: int = -1  # its place in its bus's list of devices
    open_error: StarterbusError | None = None  # opening it (in a pool thread) failed: its next poll's error


@dataclass(slots=True)
class Attempt:
    """One poll of one device being made: when it started, whether it is a probe, what it reads."""

    runtime: DeviceRuntime
    start: float
    probe: bool
    device: Device | None = None
    points: list[PointDef] = field(default_factory=list)
    before: TransportCounters | None = None


class DevicePolls:
    """A bus's devices and what one poll of one does: open it, count what it put on the wire, set its state."""

    def __init__(self, bus: BusConfig, poller: PollContext) -> None:
        self.bus = bus
        self.poller = poller
        self.devices = [DeviceRuntime(d, slot=i) for i, d in enumerate(bus.devices)]
        self.stats = LineStats(bus.name, started=poller.clock())
        self.budget = ProbeBudget(poller.probing.share, poller.probing.timeout or 1.0, poller.clock())
        self.deferred = False  # devices are closed in a pool thread (:meth:`close_dropped`), not where dropped
        self.dropped: list[Device] = []  # devices to close (``deferred``)

    # -- the devices -----------------------------------------------------------------------------------------

    def _probing(self, runtime: DeviceRuntime) -> bool:
        """An offline device is probed, not polled (unless probes are switched off)."""
        return runtime.online is False and self.poller.probing.timeout is not None

    def _close_all(self) -> None:
        for runtime in self.devices:
            self._close(runtime)
        self.close_dropped()

    def close_dropped(self) -> None:
        """Close the devices dropped while closing was ``deferred``."""
        while self.dropped:
            device = self.dropped.pop()
            try:
                device.close()
            except StarterbusError:
                pass

    def open_for_poll(self, runtime: DeviceRuntime) -> None:
        """Open the device for its next poll (in a pool thread, the bus lent), and every device of the bus never
        polled yet (the first round: one lend, not one per device); a failure is that device's next poll's
        error."""
        for other in [runtime, *(r for r in self.devices if r.polls == 0 and r is not runtime)]:
            if other.device is None and other.open_error is None:
                try:
                    self._ensure_open(other)
                except StarterbusError as exc:
                    other.open_error = exc

    # -- counting ----------------------------------------------------------------------------------------------

    @staticmethod
    def _counters(device: Device) -> TransportCounters | None:
        counters = device.transport.counters()
        return counters.copy() if counters is not None else None

    def _count(
        self, device: Device, before: TransportCounters | None, began: float, ended: float | None = None
    ) -> TransportCounters:
        """What one poll or job put on the wire (a transport that does not count: one transaction)."""
        after = device.transport.counters()
        if before is None or after is None:
            delta = TransportCounters(transactions=1, requests=1)
        else:
            delta = after.minus(before)
        delta.busy_time = (self.poller.clock() if ended is None else ended) - began  # the time the line was held
        self.stats.wire.add(delta)
        return delta

    # -- one device --------------------------------------------------------------------------------------------

    def _ensure_open(self, runtime: DeviceRuntime) -> Device:
        if runtime.device is None:
            device = open_device(runtime.config.url, runtime.config.model)
            device.open()
            runtime.device = device
        return runtime.device

    def _close(self, runtime: DeviceRuntime) -> None:
        if runtime.device is not None and self.deferred:
            self.dropped.append(runtime.device)
            runtime.device = None
        if runtime.device is not None:
            try:
                runtime.device.close()
            except StarterbusError:
                pass
            runtime.device = None

    def _what_to_read(self, runtime: DeviceRuntime, device: Device) -> list[PointDef]:
        """The points each poll reads, resolved once; keys the transport cannot read are reported once."""
        if runtime.points is None:
            points, runtime.status, skipped = poll_points(runtime.config, device)
            runtime.skipped |= skipped
            runtime.unreadable = tuple(sorted(runtime.skipped))
            runtime.points = points
        return runtime.points

    def policy(self, attempt: Attempt, device: Device) -> contextlib.AbstractContextManager[None]:
        """The rules the poll's requests follow: a probe's (one short attempt), else the transport's own."""
        timeout = self.poller.probing.timeout_for(attempt.runtime.slowest_request) if attempt.probe else None
        if timeout is None:
            return contextlib.nullcontext()
        return device.transport.probe_policy(timeout)

    def begin(self, runtime: DeviceRuntime) -> Attempt:
        """A poll of ``runtime`` starts now."""
        return Attempt(runtime, self.poller.clock(), self._probing(runtime))

    def prepare(self, attempt: Attempt) -> Device:
        """The device opened (raises what opening raises), what the poll reads, the counters before it."""
        runtime = attempt.runtime
        error, runtime.open_error = runtime.open_error, None
        if error is not None:
            raise error
        device = self._ensure_open(runtime)
        attempt.points = self._what_to_read(runtime, device)
        attempt.before = self._counters(device)
        attempt.device = device
        return device

    def abandon(self, attempt: Attempt) -> None:
        """A poll cut short (the poller stops): what it put on the line is counted; it gives no sample."""
        if attempt.device is not None:
            self._count(attempt.device, attempt.before, attempt.start)

    def _poll(self, runtime: DeviceRuntime) -> None:
        """One poll, blocking."""
        attempt = self.begin(runtime)
        result: PollResult | None = None
        error: StarterbusError | None = None
        try:
            device = self.prepare(attempt)
            with self.policy(attempt, device):
                result = device.transport.poll(attempt.points, runtime.status)
        except StarterbusError as exc:
            error = exc
        self.end(attempt, result, error)

    def end(
        self, attempt: Attempt, result: PollResult | None, error: StarterbusError | None, ended: float | None = None
    ) -> None:
        """A poll is over (``result``, or ``error``; ``ended``: when it gave the line back, if not now): count
        it, set the device's state and next time, emit the sample."""
        poller = self.poller
        runtime, start, probe = attempt.runtime, attempt.start, attempt.probe
        config = runtime.config
        device = attempt.device
        wire = self._count(device, attempt.before, start, ended) if device is not None else None
        status: Status | None = None
        values: dict[str, Value] = {}
        if result is not None and device is not None:
            try:
                status = result.status
                name = device.transport.name
                from_raw = Value.from_raw  # (Reading.value, one call less a point)
                values = {r.point.key: from_raw(r.point, r.raw, r.scale, name) for r in result.readings}
            except StarterbusError as exc:
                error = exc
        # online means answered: any error (no answer, an exception response, garbage, a URL or setting the
        # device cannot be opened with) leaves the device offline, with no values and the error said
        online = error is None
        if online and status is not None and device is not None:
            device.guard.note_status(status)  # a queued write's state rule need not read it again
        if isinstance(error, TransportError) and not isinstance(error, TimeoutError):
            self._close(runtime)  # port or socket gone: reopen on the next attempt
        now = poller.clock()
        if probe:
            runtime.probes += 1
            self.stats.probes += 1
            self.budget.spend(now - start, now)
        if error is not None:
            runtime.errors += 1
        runtime.polls += 1
        if online:
            runtime.failures_in_a_row = 0
            # the next slot of the device's grid; a poll more than a period late starts a new grid
            due = runtime.next_due + config.period
            runtime.next_due = due if due > start else start + config.period
            runtime.last_ok = now
            if wire is not None and wire.requests and not probe:
                runtime.slowest_request = max(runtime.slowest_request, (now - start) / wire.requests)
        else:
            runtime.failures_in_a_row += 1
            runtime.next_due = now + backoff(
                runtime.failures_in_a_row, config.period, poller.config.max_backoff, poller.rng
            )
        runtime.online = online
        self.stats.polls += 1
        sample = polled(
            config.name,
            config.bus,
            config.model,
            time.time(),
            online,
            status if online else None,
            values if online else {},
            None if error is None else str(error),
            runtime.errors,
            runtime.unreadable,
            wire,
            probe,
        )
        runtime.last_sample = sample
        poller.emit(sample)
