"""Polling a fleet: one worker thread per bus, one transaction at a time per bus, devices on their own periods.

A device that stops answering is marked offline at once (its values are dropped, never shown as fresh),
retried with exponential backoff up to ``max_backoff`` and comes back by itself. A bad device costs its own
bus at most its transport timeout (times the transport's retries) per attempt and never touches other buses.
Commands and writes for a device are queued to its bus worker (:meth:`FleetPoller.submit`), so they take
their turn on the line like any poll.
"""

from __future__ import annotations

import heapq
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
from starterbus.core.model import Value
from starterbus.core.status import Status
from starterbus.core.transport import Capability
from starterbus.fleet.config import BusConfig, DeviceConfig, FleetConfig

T = TypeVar("T")
Clock = Callable[[], float]


@dataclass(frozen=True, slots=True)
class Sample:
    """One poll of one device."""

    device: str
    bus: str
    model: str
    time: float  # wall clock, seconds since the epoch
    online: bool
    status: Status | None
    values: dict[str, Value]
    error: str | None
    errors: int  # errors of this device so far
    unreadable: tuple[str, ...] = ()  # configured keys this device's transport cannot read

    def as_json(self) -> dict[str, object]:
        return {
            "device": self.device,
            "bus": self.bus,
            "model": self.model,
            "time": round(self.time, 3),
            "online": self.online,
            "status": self.status.as_json() if self.status else None,
            "values": {
                k: {
                    "value": v.value,
                    "unit": v.unit,
                    "resolution": v.resolution,
                    "raw": v.raw,
                    "label": v.label.en if v.label else None,
                }
                for k, v in self.values.items()
            },
            "error": self.error,
            "errors": self.errors,
            "unreadable": list(self.unreadable),
        }


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


class BusWorker:
    def __init__(self, bus: BusConfig, poller: FleetPoller) -> None:
        self.bus = bus
        self.poller = poller
        self.devices = [DeviceRuntime(d) for d in bus.devices]
        self.jobs: list[tuple[str, Callable[[Device], Any], Future[Any]]] = []
        self.wake = threading.Event()
        self.thread = threading.Thread(target=self._run, name=f"bus-{bus.name}", daemon=True)
        self.transactions = 0

    # -- the loop -----------------------------------------------------------------------------------------

    def _run(self) -> None:
        poller = self.poller
        queue = [(0.0, i) for i in range(len(self.devices))]
        heapq.heapify(queue)
        rounds_left = poller.rounds
        done_in_round: set[int] = set()
        try:
            while not poller.stopping.is_set():
                self._run_jobs()
                due, index = queue[0]
                wait = due - poller.clock()
                if wait > 0:
                    self.wake.wait(wait)
                    self.wake.clear()
                    continue
                heapq.heappop(queue)
                runtime = self.devices[index]
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

    def _run_jobs(self) -> None:
        while self.jobs:
            name, fn, future = self.jobs.pop(0)
            runtime = next(r for r in self.devices if r.config.name == name)
            if not future.set_running_or_notify_cancel():
                continue
            try:
                device = self._ensure_open(runtime)
                future.set_result(fn(device))
                self.transactions += 1
            except BaseException as exc:  # delivered to the caller through the future
                future.set_exception(exc)

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

    def _poll(self, runtime: DeviceRuntime) -> None:
        poller = self.poller
        config = runtime.config
        start = poller.clock()
        status: Status | None = None
        values: dict[str, Value] = {}
        error: str | None = None
        online = True
        try:
            device = self._ensure_open(runtime)
            caps = device.capabilities
            if Capability.STATUS in caps:
                status = device.status()
                self.transactions += 1
            keys = [k for k in config.measurements if Capability.READ_MEASUREMENTS in caps]
            keys += [k for k in config.parameters if Capability.READ_PARAMETERS in caps]
            for k in set(config.measurements + config.parameters) - set(keys) - runtime.skipped:
                runtime.skipped.add(k)
            if keys:
                values = device.read(*keys)
                self.transactions += 1
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
        if error is not None:
            runtime.errors += 1
        runtime.polls += 1
        if online:
            runtime.failures_in_a_row = 0
            runtime.next_due = start + config.period
            if status is not None or values:
                runtime.last_ok = poller.clock()
        else:
            runtime.failures_in_a_row += 1
            backoff = min(config.period * (2 ** (runtime.failures_in_a_row - 1)), poller.config.max_backoff)
            runtime.next_due = poller.clock() + backoff
        runtime.online = online
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
    ) -> None:
        self.config = config
        self.on_sample = on_sample
        self.rounds = rounds
        self.clock = clock
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
        return sum(w.transactions for w in self.workers)
