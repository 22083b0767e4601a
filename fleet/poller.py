"""Polling a fleet: one worker thread per bus, one transaction at a time per bus, devices on their own periods.

Each poll is one :meth:`Transport.poll <starterbus.core.transport.Transport.poll>`: the status and the configured
points through the transport's poll plan (on Modbus RTU every register once, merged into the fewest requests).
A device is polled on a grid of its period, so a poll that starts late (the line was busy) does not push the
following ones back.

A device that stops answering is marked offline at once (its values are dropped, never shown as fresh). From
then on it is only probed (:mod:`starterbus.fleet.probing`): one attempt with a short timeout, with exponential
backoff and jitter up to ``max_backoff``, and all probes of a line within a bounded share of its time; it comes
back by itself. It never touches other buses. Commands and writes for a device are queued to its bus worker
(:meth:`FleetPoller.submit`), so they take their turn on the line like any poll.

Each bus worker adds up what its transports report putting on the wire (:meth:`FleetPoller.line_stats`).
"""

from __future__ import annotations

import contextlib
import heapq
import random
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any, TypeVar

from starterbus.core.device import Device, open_device
from starterbus.core.errors import (
    StarterbusError,
    TimeoutError,
    TransportError,
    UnsupportedOperationError,
)
from starterbus.core.model import PointDef, Value
from starterbus.core.status import Status
from starterbus.core.transport import TransportCounters
from starterbus.fleet.config import BusConfig, DeviceConfig, FleetConfig
from starterbus.fleet.line_stats import LineStats
from starterbus.fleet.plan import poll_points
from starterbus.fleet.probing import ProbeBudget, ProbeSettings, backoff
from starterbus.fleet.sample import Sample

T = TypeVar("T")
Clock = Callable[[], float]
_PR_SET_TIMERSLACK = 29


def _precise_timers() -> None:
    """Linux: 1 us timer slack for the calling bus worker instead of 50 us, so that a wait for the line's silent
    interval ends when the interval does (a line's throughput is a chain of such waits). Best effort."""
    try:
        import ctypes

        ctypes.CDLL(None).prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0)
    except (OSError, AttributeError):
        pass


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
    points: list[PointDef] | None = None  # what each poll reads, resolved once the device is open
    status: bool = False  # whether each poll reads the status
    slowest_request: float = 0.0  # longest time per request of a good poll, s (floor of the probe timeout)
    probes: int = 0


class BusWorker:
    def __init__(self, bus: BusConfig, poller: FleetPoller) -> None:
        self.bus = bus
        self.poller = poller
        self.devices = [DeviceRuntime(d) for d in bus.devices]
        self.jobs: list[tuple[str, Callable[[Device], Any], Future[Any]]] = []
        self.wake = threading.Event()
        self.thread = threading.Thread(target=self._run, name=f"bus-{bus.name}", daemon=True)
        self.stats = LineStats(bus.name, started=poller.clock())
        self.budget = ProbeBudget(poller.probing.share, poller.probing.timeout or 1.0, poller.clock())

    @property
    def transactions(self) -> int:
        return self.stats.wire.transactions

    # -- the loop -----------------------------------------------------------------------------------------

    def _run(self) -> None:
        poller = self.poller
        queue = [(0.0, i) for i in range(len(self.devices))]
        heapq.heapify(queue)
        rounds_left = poller.rounds
        done_in_round: set[int] = set()
        self.stats.started = poller.clock()
        _precise_timers()
        try:
            while not poller.stopping.is_set():
                self._run_jobs()
                due, index = queue[0]
                now = poller.clock()
                runtime = self.devices[index]
                later = self.start_time(due, runtime, now)
                if later > due:
                    heapq.heapreplace(queue, (later, index))
                    continue
                wait = due - now
                if wait > 0:
                    self.wake.wait(wait)
                    self.wake.clear()
                    continue
                heapq.heappop(queue)
                runtime.next_due = due
                self._poll(runtime)
                if self.bus.delay:
                    poller.stopping.wait(self.bus.delay)
                heapq.heappush(queue, (runtime.next_due, index))
                if rounds_left is not None:
                    done_in_round.add(index)
                    if len(done_in_round) == len(self.devices):
                        done_in_round.clear()
                        rounds_left -= 1
                        if rounds_left <= 0:
                            break
                        queue = [(0.0, i) for i in range(len(self.devices))]
        finally:
            self._run_jobs()
            for runtime in self.devices:
                self._close(runtime)
            self.stats.stopped = poller.clock()

    def start_time(self, due: float, runtime: DeviceRuntime, now: float) -> float:
        """When a device's poll due at ``due`` may start: then, or for a probe of an offline device, once the
        line's probe budget allows it."""
        if due <= now and self._probing(runtime):
            wait = self.budget.wait(now)
            if wait > 0:
                return now + wait
        return due

    def _probing(self, runtime: DeviceRuntime) -> bool:
        """An offline device is probed, not polled (unless probes are switched off)."""
        return runtime.online is False and self.poller.probing.timeout is not None

    def _run_jobs(self) -> None:
        while self.jobs:
            name, fn, future = self.jobs.pop(0)
            runtime = next(r for r in self.devices if r.config.name == name)
            if not future.set_running_or_notify_cancel():
                continue
            try:
                device = self._ensure_open(runtime)
                before, began = self._counters(device), self.poller.clock()
                try:
                    future.set_result(fn(device))
                finally:
                    self._count(device, before, began)
            except BaseException as exc:  # delivered to the caller through the future
                future.set_exception(exc)

    # -- counting -----------------------------------------------------------------------------------------

    @staticmethod
    def _counters(device: Device) -> TransportCounters | None:
        counters = device.transport.counters()
        return counters.copy() if counters is not None else None

    def _count(self, device: Device, before: TransportCounters | None, began: float) -> TransportCounters:
        """What one poll or job put on the wire (a transport that does not count: one transaction)."""
        after = device.transport.counters()
        if before is None or after is None:
            delta = TransportCounters(transactions=1, requests=1)
        else:
            delta = after.minus(before)
        delta.busy_time = self.poller.clock() - began  # the time this worker held the line
        self.stats.wire.add(delta)
        return delta

    # -- one device ---------------------------------------------------------------------------------------

    def _ensure_open(self, runtime: DeviceRuntime) -> Device:
        if runtime.device is None:
            device = open_device(runtime.config.url, runtime.config.model)
            device.open()
            runtime.device = device
        return runtime.device

    def _close(self, runtime: DeviceRuntime) -> None:
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
            runtime.points = points
        return runtime.points

    def _poll(self, runtime: DeviceRuntime) -> None:
        poller = self.poller
        config = runtime.config
        start = poller.clock()
        probe = self._probing(runtime)
        status: Status | None = None
        values: dict[str, Value] = {}
        error: str | None = None
        online = True
        wire: TransportCounters | None = None
        try:
            device = self._ensure_open(runtime)
            points = self._what_to_read(runtime, device)
            transport = device.transport
            timeout = poller.probing.timeout_for(runtime.slowest_request) if probe else None
            policy = transport.probe_policy(timeout) if timeout is not None else contextlib.nullcontext()
            before = self._counters(device)
            try:
                with policy:
                    result = transport.poll(points, runtime.status)
            finally:
                wire = self._count(device, before, start)
            status = result.status
            if status is not None:
                device.guard.note_status(status)  # a queued write's state rule need not read it again
            values = {r.point.key: r.value(transport.name) for r in result.readings}
        except (TimeoutError, TransportError) as exc:
            online = False
            error = str(exc)
            if not isinstance(exc, TimeoutError):
                self._close(runtime)  # port or socket gone: reopen on the next attempt
        except UnsupportedOperationError as exc:
            error = str(exc)
        except StarterbusError as exc:  # the device answered, but with an error or garbage
            error = str(exc)
            status, values = None, {}
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
            if status is not None or values:
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
        sample = Sample(
            device=config.name,
            bus=config.bus,
            model=config.model,
            time=time.time(),
            online=online,
            status=status if online else None,
            values=values if online else {},
            error=error,
            errors=runtime.errors,
            unreadable=tuple(sorted(runtime.skipped)),
            wire=wire,
            probe=probe,
        )
        runtime.last_sample = sample
        poller._emit(sample)


class FleetPoller:
    """Polls every device of a fleet; all buses concurrently, each bus strictly one transaction at a time."""

    def __init__(
        self,
        config: FleetConfig,
        on_sample: Callable[[Sample], None] | None = None,
        *,
        rounds: int | None = None,
        clock: Clock = time.monotonic,
        probing: ProbeSettings | None = None,
        rng: random.Random | None = None,
    ) -> None:
        self.config = config
        self.on_sample = on_sample
        self.rounds = rounds
        self.clock = clock
        self.probing = probing or ProbeSettings()
        self.rng = rng or random.Random()
        self.stopping = threading.Event()
        self.workers = [BusWorker(bus, self) for bus in config.buses]
        self._emit_lock = threading.Lock()

    def _emit(self, sample: Sample) -> None:
        if self.on_sample is not None:
            with self._emit_lock:
                self.on_sample(sample)

    def start(self) -> FleetPoller:
        for worker in self.workers:
            worker.thread.start()
        return self

    def stop(self, timeout: float = 10.0) -> None:
        self.stopping.set()
        for worker in self.workers:
            worker.wake.set()
        self.join(timeout)

    def join(self, timeout: float | None = None) -> None:
        deadline = None if timeout is None else time.monotonic() + timeout
        for worker in self.workers:
            if worker.thread.is_alive():
                worker.thread.join(None if deadline is None else max(0.0, deadline - time.monotonic()))

    @property
    def running(self) -> bool:
        return any(w.thread.is_alive() for w in self.workers)

    def __enter__(self) -> FleetPoller:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def runtimes(self) -> list[DeviceRuntime]:
        return [r for w in self.workers for r in w.devices]

    def submit(self, device: str, fn: Callable[[Device], T]) -> Future[T]:
        """Run ``fn(device)`` in the device's bus worker, between polls; returns a Future of its result."""
        for worker in self.workers:
            if any(r.config.name == device for r in worker.devices):
                future: Future[T] = Future()
                worker.jobs.append((device, fn, future))
                worker.wake.set()
                if not worker.thread.is_alive():
                    worker._run_jobs()
                return future
        raise StarterbusError(f"no device named {device!r} in the fleet")

    def transactions(self) -> int:
        """Transactions so far on every bus (a transaction: one request and its answer, retries apart)."""
        return sum(w.transactions for w in self.workers)

    def line_stats(self) -> dict[str, LineStats]:
        """Per bus: what went over its wire so far and how busy the line was (copies, safe to keep)."""
        now = self.clock()
        return {w.bus.name: w.stats.snapshot(now) for w in self.workers}


__all__ = ["BusWorker", "DeviceRuntime", "FleetPoller", "Sample"]
