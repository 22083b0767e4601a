"""Polling a fleet: all buses concurrently, each bus strictly one transaction at a time, devices on their own
periods (the rules per bus: :mod:`starterbus.fleet.bus_worker`).

Buses whose transports can poll without blocking (``Transport.start_poll``: Modbus RTU on a file descriptor,
Modbus TCP) are polled from the process's scheduler, whose one thread waits on all their lines at once
(:mod:`starterbus.fleet.mux`); their jobs, and the opening and closing of their devices, run in a small pool
of threads shared by those buses. Any other bus is polled by a thread of its own. Commands and writes for a
device are queued to its bus (:meth:`FleetPoller.submit`), so they take their turn on the line like any poll.
Each bus adds up what its transports report putting on the wire (:meth:`FleetPoller.line_stats`).
"""

from __future__ import annotations

import functools
import os
import random
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import TypeVar

from starterbus.core.device import Device
from starterbus.core.errors import StarterbusError
from starterbus.core.registry import get_profile, get_transport
from starterbus.core.supervision import ServiceFailed, Supervisor
from starterbus.core.url import DeviceUrl
from starterbus.fleet.bus_worker import BusWorker
from starterbus.fleet.config import BusConfig, FleetConfig
from starterbus.fleet.device_poll import DeviceRuntime
from starterbus.fleet.line_stats import LineStats
from starterbus.fleet.mux import Multiplexer
from starterbus.fleet.probing import ProbeSettings
from starterbus.fleet.sample import Sample

T = TypeVar("T")
Clock = Callable[[], float]


def polls_without_blocking(bus: BusConfig) -> bool:
    """Whether the bus's transport offers :class:`~starterbus.core.polling.PollTask` polls (judged from its
    class, without opening anything; a bad URL or model is reported by the first poll, as for any bus)."""
    for device in bus.devices:
        try:
            url = DeviceUrl.parse(device.url)
            transport = get_transport(url.transport).open(url, get_profile(device.model))
        except StarterbusError:
            continue
        return type(transport).offers_poll_tasks()
    return False


class FleetPoller:
    """Polls every device of a fleet; all buses concurrently, each bus strictly one transaction at a time.

    ``multiplex=False`` gives every bus a thread of its own (the way before :mod:`starterbus.fleet.mux`; the
    benchmark compares both).

    Its threads run under ``supervisor`` (:mod:`starterbus.core.supervision`; one of its own if not given): an
    unexpected exception in a bus's polls or in ``on_sample`` is contained (logged, counted under the bus's
    thread name, the bus's devices closed and the bus resumed after a backoff); one in the machinery around
    them stops the poller, with :attr:`failure` set.
    """

    def __init__(
        self,
        config: FleetConfig,
        on_sample: Callable[[Sample], None] | None = None,
        *,
        rounds: int | None = None,
        clock: Clock = time.monotonic,
        probing: ProbeSettings | None = None,
        rng: random.Random | None = None,
        multiplex: bool = True,
        supervisor: Supervisor | None = None,
    ) -> None:
        self.config = config
        self.supervisor = supervisor or Supervisor()
        self.on_sample = on_sample
        self.rounds = rounds
        self.clock = clock
        self.probing = probing or ProbeSettings()
        self.rng = rng or random.Random()
        self.stopping = threading.Event()
        self.workers = [BusWorker(bus, self) for bus in config.buses]
        multiplex = multiplex and os.name == "posix"  # select() on serial ports, ptys and a pipe
        shared = [w for w in self.workers if multiplex and polls_without_blocking(w.bus)]
        self.mux = Multiplexer(self, shared) if shared else None
        self._own_thread = [w for w in self.workers if w not in shared]
        self._emit_lock = threading.Lock()
        self.supervisor.on_fatal(lambda _failure: self.request_stop())

    @property
    def failure(self) -> ServiceFailed | None:
        """What stopped the poller against its will (None while it runs, and after a requested stop)."""
        return self.supervisor.failure

    def emit(self, sample: Sample) -> None:
        """Hand a sample to ``on_sample``, one at a time (called by the bus workers)."""
        if self.on_sample is not None:
            with self._emit_lock:
                self.on_sample(sample)

    def start(self) -> FleetPoller:
        for worker in self._own_thread:
            worker.thread.start()
        if self.mux is not None:
            self.mux.start()
        return self

    def stop(self, timeout: float = 10.0) -> None:
        """Stop polling and wait (up to ``timeout``) until every bus is done; called from one of the poller's
        own threads (``on_sample``, a job) it does not wait: those threads may wait for the caller."""
        self.request_stop()
        own = threading.current_thread() in self._threads() or (self.mux is not None and self.mux.own_thread())
        if not own:
            self.join(timeout)

    def request_stop(self) -> None:
        """Stop polling, without waiting (a signal handler, a fatal failure)."""
        self.stopping.set()
        for worker in self.workers:
            worker.wake.set()
        if self.mux is not None:
            self.mux.wake()

    def _threads(self) -> list[threading.Thread]:
        threads = [w.thread for w in self.workers]
        if self.mux is not None:
            threads += [self.mux.thread, *self.mux.lent()]
        return threads

    def join(self, timeout: float | None = None) -> None:
        deadline = None if timeout is None else time.monotonic() + timeout

        def wait_for(thread: threading.Thread) -> None:
            if thread.is_alive():
                thread.join(None if deadline is None else max(0.0, deadline - time.monotonic()))

        if self.mux is not None:
            self.mux.join(None if deadline is None else max(0.0, deadline - time.monotonic()))
        # then each bus's thread, as it is now: one the multiplexer handed a bus to is known once it is over
        for worker in self.workers:
            wait_for(worker.thread)

    @property
    def running(self) -> bool:
        return any(w.thread.is_alive() for w in self.workers) or (self.mux is not None and self.mux.alive)

    def __enter__(self) -> FleetPoller:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _driven(self, worker: BusWorker) -> bool:
        """Whether a thread polls ``worker``'s bus now (and so will run its jobs)."""
        if worker.thread.is_alive():
            return True
        return self.mux is not None and self.mux.driving and worker not in self._own_thread

    def runtimes(self) -> list[DeviceRuntime]:
        return [r for w in self.workers for r in w.devices]

    def submit(
        self, device: str, fn: Callable[[Device], T], *, elsewhere: Callable[[Callable[[], None]], object] | None = None
    ) -> Future[T]:
        """Run ``fn(device)`` on the device's bus, between polls; returns a Future of its result. Before the
        poller starts, and once it is over, the job runs at once in the calling thread (after the end on the
        device opened for it and closed again), or, given ``elsewhere`` (a pool's ``run``), there: a caller that
        must not block (an event loop) never runs it, even when the end comes between its look and the submit."""
        for worker in self.workers:
            if any(r.config.name == device for r in worker.devices):
                future: Future[T] = Future()
                job = (device, fn, future)
                if not worker.jobs.put(job):
                    if elsewhere is None:
                        worker.run_after_the_end(job)
                    else:
                        elsewhere(functools.partial(worker.run_after_the_end, job))
                elif self._driven(worker):
                    worker.notify()
                elif elsewhere is None:  # not started yet: at once, on the device the polls will use
                    worker.run_jobs()
                else:
                    elsewhere(worker.run_jobs)
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
