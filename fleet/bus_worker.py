"""One bus of a fleet: its devices' schedule, their polls and what they put on the wire; one transaction at a
time per bus, devices on their own periods.

Each poll is one :meth:`Transport.poll <starterbus.core.transport.Transport.poll>`: the status and the configured
points through the transport's poll plan (on Modbus RTU every register once, merged into the fewest requests),
run by the bus's own thread (:meth:`BusWorker.run`) or, where the transports offer it, as a
:class:`~starterbus.core.polling.PollTask` that one thread advances for many buses (:mod:`starterbus.fleet.mux`).
A device is polled on a grid of its period, so a poll that starts late (the line was busy) does not push the
following ones back. What one poll of one device does (opening it, counting its wire, its state, next time and
sample) is the base class's, :class:`~starterbus.fleet.device_poll.DevicePolls`.

A device that stops answering is marked offline at once (its values are dropped, never shown as fresh). From
then on it is only probed (:mod:`starterbus.fleet.probing`): one attempt with a short timeout, with exponential
backoff and jitter up to ``max_backoff``, and all probes of a line within a bounded share of its time; it comes
back by itself. It never touches other buses. Commands and writes for a device are queued to its bus worker
(:meth:`FleetPoller.submit <starterbus.fleet.poller.FleetPoller.submit>`), so they take their turn on the line
like any poll.

Each bus worker adds up what its transports report putting on the wire (:meth:`FleetPoller.line_stats`).
"""

from __future__ import annotations

import heapq
import threading
from collections.abc import Callable

from starterbus.core.media.waiter import precise_timers
from starterbus.fleet.config import BusConfig
from starterbus.fleet.device_poll import DevicePolls, DeviceRuntime
from starterbus.fleet.jobs import Job, JobQueue
from starterbus.fleet.poll_context import PollContext


class BusWorker(DevicePolls):
    """One bus: the devices' schedule (a queue of due times), their polls and jobs, the line's counts."""

    def __init__(self, bus: BusConfig, poller: PollContext) -> None:
        super().__init__(bus, poller)
        self.jobs = JobQueue()
        self.wake = threading.Event()
        self.name = f"bus-{bus.name}"  # its thread's, and its name for the supervisor
        self.thread = poller.supervisor.thread(self.name, self.run)
        self.queue = [(0.0, i) for i in range(len(self.devices))]  # (due, device index), a heap
        self.rounds_left = poller.rounds
        self.done_in_round: set[int] = set()
        self.finished = False  # the rounds asked for are done
        self.notify: Callable[[], None] = self.wake.set  # tells whoever drives the bus that a job is queued
        self.lent = False  # a pool thread has the bus (a job, a device opened or closed): its polls wait

    @property
    def transactions(self) -> int:
        return self.stats.wire.transactions

    # -- the schedule ----------------------------------------------------------------------------------------

    def next_due(self, now: float) -> tuple[float, int]:
        """(due time, device index) of the next poll: the head of the queue, once probes that the line's probe
        budget holds back have been moved to when it allows them."""
        queue = self.queue
        while True:
            due, index = queue[0]
            later = self.start_time(due, self.devices[index], now)
            if later <= due:
                return due, index
            heapq.heapreplace(queue, (later, index))

    def take(self, due: float) -> DeviceRuntime:
        """The device at the head of the queue (due at ``due``) leaves it to be polled."""
        _, index = heapq.heappop(self.queue)
        runtime = self.devices[index]
        runtime.next_due = due
        return runtime

    def polled(self, runtime: DeviceRuntime) -> None:
        """Back in the queue at its next due time; counts the rounds asked for (``finished`` when done)."""
        index = runtime.slot
        heapq.heappush(self.queue, (runtime.next_due, index))
        if self.rounds_left is not None:
            self.done_in_round.add(index)
            if len(self.done_in_round) == len(self.devices):
                self.done_in_round.clear()
                self.rounds_left -= 1
                if self.rounds_left <= 0:
                    self.finished = True
                self.queue = [(0.0, i) for i in range(len(self.devices))]

    def ends_round(self, runtime: DeviceRuntime) -> bool:
        """Whether ``runtime``'s poll, once over, completes a round of the rounds asked for (the next poll then
        starts only after :meth:`polled`, which decides whether there is one)."""
        if self.rounds_left is None:
            return False
        return len(self.done_in_round | {runtime.slot}) == len(self.devices)

    def start_time(self, due: float, runtime: DeviceRuntime, now: float) -> float:
        """When a device's poll due at ``due`` may start: then, or for a probe of an offline device, once the
        line's probe budget allows it."""
        if due <= now and self._probing(runtime):
            wait = self.budget.wait(now)
            if wait > 0:
                return now + wait
        return due

    # -- the bus's own thread (transports that poll only by blocking) ------------------------------------------

    def run(self, first: DeviceRuntime | None = None) -> None:
        """Poll the bus until the poller stops or the rounds are done; ``first``: a device already taken from
        the queue (the multiplexer hands over a bus whose transport cannot poll without blocking)."""
        poller = self.poller
        self.stats.started = poller.clock() if first is None else self.stats.started
        precise_timers()
        try:
            if first is not None:
                self._contained(self._poll_and_pause, first)
            while not poller.stopping.is_set() and not self.finished:
                self._contained(self._step)
        finally:
            self.shut_down()

    def _step(self) -> None:
        """The queued jobs, then the next poll or a wait until it is due (or a job comes)."""
        self.run_jobs()
        now = self.poller.clock()
        due, _ = self.next_due(now)
        wait = due - now
        if wait > 0:
            self.wake.wait(wait)
            self.wake.clear()
            return
        self._poll_and_pause(self.take(due))

    def _contained(self, step: Callable[..., None], *args: DeviceRuntime) -> None:
        """``step(*args)``; an unexpected exception (``on_sample`` raised, a bug) is the supervisor's: counted,
        logged, and the bus starts afresh after the backoff."""
        try:
            step(*args)
        except Exception as exc:
            pause = self.poller.supervisor.contain(self.name, exc)
            self.restart(self.poller.clock() + pause)
            self.poller.stopping.wait(pause)

    def restart(self, at: float) -> None:
        """After a contained failure: the devices closed (reopened by their next poll), every device due at
        ``at`` (a poll cut short left its device out of the queue)."""
        self._close_all()
        self.queue = [(at, i) for i in range(len(self.devices))]

    def _poll_and_pause(self, runtime: DeviceRuntime) -> None:
        """One poll, then the bus's ``delay`` before anything else goes on its line."""
        self._poll(runtime)
        if self.bus.delay:
            self.poller.stopping.wait(self.bus.delay)
        self.polled(runtime)

    def shut_down(self) -> None:
        """The end: the jobs queued until now run, the devices are closed (a job submitted meanwhile waits, then
        runs after the end: :meth:`run_after_the_end`)."""
        with self.jobs.lock:
            self.jobs.close()
            self.run_jobs()
            self._close_all()
        self.stats.stopped = self.poller.clock()

    def run_after_the_end(self, job: Job) -> None:
        """A job that came after :meth:`shut_down`: run in the calling thread, on its device opened for it."""
        with self.jobs.lock:  # one such job at a time: no other thread uses the bus any more
            try:
                self._run(job)
            finally:
                self._close_all()

    def run_jobs(self) -> None:
        while (job := self.jobs.pop()) is not None:
            self._run(job)

    def _run(self, job: Job) -> None:
        name, fn, future = job
        runtime = next(r for r in self.devices if r.config.name == name)
        if not future.set_running_or_notify_cancel():
            return
        try:
            device = self._ensure_open(runtime)
            before, began = self._counters(device), self.poller.clock()
            try:
                future.set_result(fn(device))
            finally:
                self._count(device, before, began)
        except BaseException as exc:  # delivered to the caller through the future
            future.set_exception(exc)


__all__ = ["BusWorker"]
