"""One thread polling many buses at once: each poll a :class:`~starterbus.core.polling.PollTask`, all waited on
with one selector.

A thread per bus spends most of its CPU handing the interpreter lock to the other bus threads around every
``select`` and ``read``; one thread that waits on every line's descriptor and timer at once does the same work
without the hand-overs and wakes for whichever line is due (bench/fleet/rtu_scale.py measures both). Per bus
the rules are those of :class:`~starterbus.fleet.bus_worker.BusWorker`, which keeps the schedule and the
bookkeeping: one poll at a time, devices on their grids, probes within the line's budget, ``delay`` between
polls. A job (command, write) for a device on a multiplexed bus runs in a thread of its own while that bus
is lent to it; its other buses go on. A bus whose transport polls only by blocking (``start_poll`` gives
None: a pyserial port without a file descriptor) is handed to a thread of its own at its first poll.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass

from starterbus.core.errors import StarterbusError, TransportError
from starterbus.core.media.waiter import precise_timers
from starterbus.core.polling import PollResult, PollTask
from starterbus.core.scheduler import FD_SETSIZE, Waiter
from starterbus.fleet.bus_worker import Attempt, BusWorker, DeviceRuntime
from starterbus.fleet.poll_context import PollContext

#: longest sleep when nothing is due (a stop or a job wakes the thread at once anyway)
IDLE = 1.0

__all__ = ["FD_SETSIZE", "IDLE", "Multiplexer", "Waiter"]  # Waiter: core.scheduler's, the fleet's before


@dataclass(slots=True)
class _Bus:
    worker: BusWorker
    task: PollTask | None = None
    attempt: Attempt | None = None
    fd: int = -1  # the descriptor registered for the task
    free_at: float = 0.0  # the bus's ``delay`` after a poll
    lent: threading.Thread | None = None  # a job thread that has the bus
    returned: bool = False  # the job thread is done with it
    crash: StarterbusError | None = None  # what went wrong where a task raised what it should not
    handed_over: bool = False  # to a thread of its own


class Multiplexer:
    """Polls the given buses from one thread (:meth:`start`); stops with the poller."""

    def __init__(self, poller: PollContext, workers: list[BusWorker]) -> None:
        self.poller = poller
        self.buses = [_Bus(w) for w in workers]
        self.thread = poller.supervisor.thread("bus-mux", self._run)  # fatal: the loop itself failing stops all
        self._wake_r, self._wake_w = -1, -1  # a pipe from start() to the end of the loop
        self._wake_lock = threading.Lock()  # closing the pipe vs writing to it: never to a reused descriptor
        self._waiter: Waiter[_Bus | None] = Waiter()
        for bus in self.buses:
            bus.worker.notify = self.wake

    def start(self) -> None:
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._waiter.register(self._wake_r, None)
        self.thread.start()

    def wake(self) -> None:
        """Look at the buses again now (a job was queued, the poller stops); nothing once the loop is over."""
        with self._wake_lock:
            if self._wake_w < 0:
                return
            try:
                os.write(self._wake_w, b"!")
            except BlockingIOError:  # already woken (the pipe is full)
                pass

    def lent(self) -> list[threading.Thread]:
        """The threads running jobs now."""
        return [b.lent for b in self.buses if b.lent is not None]

    @property
    def alive(self) -> bool:
        return self.thread.is_alive() or any(t.is_alive() for t in self.lent())

    # -- the loop --------------------------------------------------------------------------------------------

    def _run(self) -> None:
        poller = self.poller
        clock = poller.clock
        precise_timers()
        for bus in self.buses:
            bus.worker.stats.started = clock()
        try:
            while not poller.stopping.is_set():
                now = clock()
                until = now + IDLE
                busy = False
                for bus in self.buses:
                    if bus.handed_over:
                        continue
                    if bus.task is None:
                        self._serve(bus, now)
                    if bus.task is not None:
                        until = min(until, bus.task.wake_at)
                        busy = True
                    elif bus.lent is not None:
                        busy = True
                    elif bus.worker.jobs or not bus.worker.finished:
                        busy = True
                        if bus.free_at > now:  # its ``delay`` first, then a job or a poll
                            until = min(until, bus.free_at)
                        elif not bus.worker.finished:
                            until = min(until, bus.worker.next_due(now)[0])
                if not busy:
                    break  # every bus has done its rounds (or has a thread of its own)
                try:
                    ready = self._waiter.wait(max(0.0, until - clock()))
                except OSError:  # a descriptor closed under a task (by another thread): fail that poll
                    ready = []
                    self._drop_closed()
                now = clock()
                for which in ready:
                    if which is None:
                        self._drain()
                    else:
                        self._serve(which, now)
                for bus in self.buses:
                    if bus.task is not None and bus.task.wake_at <= now:
                        self._serve(bus, now)
        finally:
            self._shut_down()

    def _serve(self, bus: _Bus, now: float) -> None:
        """:meth:`_service`; an exception that is not the line's (``on_sample`` raised, a bug) is contained for
        this bus alone (:meth:`BusWorker._contained <starterbus.fleet.bus_worker.BusWorker>`): counted and
        logged by the supervisor, its poll cancelled, its devices closed, the bus resumed after the backoff; the
        other buses go on."""
        try:
            self._service(bus, now)
        except Exception as exc:
            worker = bus.worker
            pause = self.poller.supervisor.contain(worker.name, exc)
            self._stop_bus(bus)
            resume = self.poller.clock() + pause
            worker.restart(resume)
            bus.free_at = resume

    def _service(self, bus: _Bus, now: float) -> None:
        """Advance the bus's poll; when it is over, start the next one that is due at once (the line's
        silence after the last answer is already behind it)."""
        while True:
            task = bus.task
            if task is not None:
                self._step(bus, task, now)
                if not task.done:
                    self._watch(bus, task.fd)
                    return
                attempt, bus.task, bus.attempt = bus.attempt, None, None
                assert attempt is not None
                try:
                    result: PollResult | None = task.result()
                    error: StarterbusError | None = None
                except StarterbusError as exc:
                    result, error = None, bus.crash or exc
                bus.crash = None
                worker = bus.worker
                if (
                    error is None
                    and not attempt.probe
                    and not worker.bus.delay
                    and worker.queue
                    and not worker.ends_round(attempt.runtime)
                ):
                    # a good poll leaves the line silent and healthy: the next request goes out first, this
                    # poll's bookkeeping follows while its answer is on the way (not after the last poll of a
                    # round: whether another poll follows is decided by that bookkeeping)
                    ended = self.poller.clock()
                    following = self._next(bus, now, lend=False) and self._task(bus)
                    if following:
                        self._step(bus, following, self.poller.clock())
                    self._end(bus, attempt, result, error, ended)
                    if following and not following.done:
                        self._watch(bus, following.fd)
                        return
                    now = self.poller.clock()
                    continue
                self._end(bus, attempt, result, error)
                now = self.poller.clock()
            if not self._next(bus, now):
                self._watch(bus, -1)
                return

    @staticmethod
    def _step(bus: _Bus, task: PollTask, now: float) -> None:
        """``task.advance(now)``; a defect in a transport fails its poll instead of stopping every bus."""
        try:
            task.advance(now)
        except Exception as exc:
            task.cancel()
            bus.crash = TransportError(f"{bus.worker.bus.name}: the poll failed: {type(exc).__name__}: {exc}")

    @staticmethod
    def _task(bus: _Bus) -> PollTask | None:
        return bus.task

    def _next(self, bus: _Bus, now: float, lend: bool = True) -> bool:
        """Between polls: return a lent bus, lend it for queued jobs, or start the poll that is due (True);
        jobs and polls alike only once the bus's ``delay`` after the last poll is over. ``lend=False``: the last
        poll's bookkeeping is still to come, queued jobs wait for it (a job would use its device meanwhile)."""
        worker = bus.worker
        if bus.lent is not None:
            if not bus.returned:
                return False
            bus.lent.join()
            bus.lent = None
        if bus.free_at > now:
            return False
        if worker.jobs:
            if not lend:
                return False
            bus.returned = False
            bus.lent = self.poller.supervisor.thread(f"jobs-{worker.bus.name}", self._jobs, bus)
            bus.lent.start()
            return False
        if worker.finished or self.poller.stopping.is_set():
            return False
        due, _ = worker.next_due(now)
        if due > now:
            return False
        runtime = worker.take(due)
        attempt = bus.attempt = worker.begin(runtime)
        try:
            device = worker.prepare(attempt)
            with worker.policy(attempt, device):
                task = device.transport.start_poll(attempt.points, runtime.status)
        except StarterbusError as exc:
            bus.attempt = None
            self._end(bus, attempt, None, exc)
            return True
        if task is None:
            self._hand_over(bus, runtime)
            return False
        bus.task = task
        return True

    def _jobs(self, bus: _Bus) -> None:
        try:
            bus.worker.run_jobs()
        finally:
            bus.returned = True
            self.wake()

    def _watch(self, bus: _Bus, fd: int) -> None:
        """Wait on ``fd`` for the bus (-1: on nothing) instead of what it waited on."""
        if fd == bus.fd:
            return
        if bus.fd >= 0:
            self._waiter.unregister(bus.fd)
        bus.fd = fd
        if fd >= 0:
            self._waiter.register(fd, bus)

    def _end(
        self,
        bus: _Bus,
        attempt: Attempt,
        result: PollResult | None,
        error: StarterbusError | None,
        ended: float | None = None,
    ) -> None:
        worker = bus.worker
        worker.end(attempt, result, error, ended)
        if worker.bus.delay:
            bus.free_at = self.poller.clock() + worker.bus.delay
        worker.polled(attempt.runtime)

    def _hand_over(self, bus: _Bus, runtime: DeviceRuntime) -> None:
        """This bus polls by blocking: it gets a thread of its own, starting with ``runtime``'s poll."""
        bus.handed_over = True
        bus.attempt = None
        worker = bus.worker
        worker.notify = worker.wake.set
        worker.thread = self.poller.supervisor.thread(worker.name, worker.run, runtime)
        worker.thread.start()

    def _drop_closed(self) -> None:
        for bus in self.buses:
            if bus.task is not None and bus.fd >= 0:
                try:
                    os.fstat(bus.fd)
                except OSError as exc:
                    bus.task.cancel()
                    bus.crash = TransportError(f"{bus.worker.bus.name}: the line was closed under the poll: {exc}")
                    self._watch(bus, -1)
                    self._serve(bus, self.poller.clock())

    def _drain(self) -> None:
        try:
            while os.read(self._wake_r, 512):
                pass
        except (BlockingIOError, OSError):
            pass

    def _stop_bus(self, bus: _Bus) -> None:
        """Cancel the bus's poll in flight (what it sent is counted), wait for a job that has the bus."""
        if bus.task is not None:
            bus.task.cancel()
            bus.task = None
        self._watch(bus, -1)
        if bus.attempt is not None:
            bus.worker.abandon(bus.attempt)
            bus.attempt = None
        if bus.lent is not None:
            bus.lent.join()
            bus.lent = None

    def _shut_down(self) -> None:
        for bus in self.buses:  # every line given back first
            self._stop_bus(bus)
        for bus in self.buses:
            if not bus.handed_over:
                bus.worker.shut_down()
        self._waiter.close()
        with self._wake_lock:
            os.close(self._wake_r)
            os.close(self._wake_w)
            self._wake_r, self._wake_w = -1, -1
