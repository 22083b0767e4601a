"""The fleet's buses on the process's scheduler (docs/engine.md, step 4): each bus a driver of its loop
(:class:`~starterbus.fleet.bus_driver.Bus`), each poll a :class:`~starterbus.core.polling.PollTask` advanced
from it, so one thread (``starterbus-io``) waits on every line at once.

A thread per bus spends most of its CPU handing the interpreter lock to the other bus threads around every
``select`` and ``read``; one thread that waits on every line's descriptor and timer at once does the same work
without the hand-overs and wakes for whichever line is due (bench/fleet/rtu_scale.py measures both). Per bus
the rules are those of :class:`~starterbus.fleet.bus_worker.BusWorker`, which keeps the schedule and the
bookkeeping: one poll at a time, devices on their grids, probes within the line's budget, ``delay`` between
polls; :meth:`BusWorker.end <starterbus.fleet.bus_worker.BusWorker.end>` is a poll's completion callback.

What may block runs in the fleet's small job pool (:func:`~starterbus.fleet.jobs.job_pool`), never in the loop:
jobs (commands, writes), and opening and closing devices (a transport's ``open`` may wait on the loop itself).
The bus is lent meanwhile (``BusWorker.lent``): its polls wait, the other buses go on. A bus whose transport
polls only by blocking (``start_poll`` gives None: a pyserial port without a file descriptor) is handed to a
thread of its own at its first poll.

The fleet holds the loop's own thread (``Scheduler.hold``: started if it does not run) from its start to its
end, counted with the loop's other holders (other fleets, devices kept running): the last one to let go stops
it, whoever started it. The loop itself failing is told to every holder: fatal for the fleet (its supervisor's
failure, named ``starterbus-io``), whoever started the thread.
"""

from __future__ import annotations

import functools
import threading
import time
from collections.abc import Callable

from starterbus.core.errors import StarterbusError, TransportError
from starterbus.core.polling import PollResult, PollTask
from starterbus.core.scheduler import FD_SETSIZE, THREAD_NAME, Holder, Scheduler, Waiter, scheduler
from starterbus.fleet.bus_driver import Bus
from starterbus.fleet.bus_worker import BusWorker
from starterbus.fleet.device_poll import Attempt, DeviceRuntime
from starterbus.fleet.jobs import POOL_SIZE, job_pool
from starterbus.fleet.poll_context import PollContext

__all__ = ["FD_SETSIZE", "Multiplexer", "Waiter"]  # Waiter: core.scheduler's, the fleet's before

INF = float("inf")


class Multiplexer:
    """Polls the given buses from the scheduler's loop (:meth:`start`); stops with the poller."""

    def __init__(self, poller: PollContext, workers: list[BusWorker], loop: Scheduler | None = None) -> None:
        self.poller = poller
        self._loop = loop  # the process's, made at start (a poller never started holds no descriptor)
        self.buses = [Bus(w, self.serve) for w in workers]
        #: the loop's thread the fleet runs on (held from its start to its end; before, a thread never started)
        self.thread = threading.Thread(name=THREAD_NAME, daemon=True)
        self._holder = Holder(f"fleet ({len(self.buses)} buses)", self._loop_failed)
        self.pool = job_pool(poller.supervisor, min(POOL_SIZE, len(workers)))
        self._started = False
        self._finishing = False  # the end is decided: the buses are no longer stepped
        self._ended = threading.Event()  # every bus given back and shut down
        for bus in self.buses:
            bus.poke = bus.worker.notify = functools.partial(self._poke, bus)

    @property
    def loop(self) -> Scheduler:
        if self._loop is None:
            self._loop = scheduler()
        return self._loop

    def start(self) -> None:
        clock = self.poller.clock
        for bus in self.buses:
            bus.worker.stats.started = clock()
            bus.worker.deferred = True  # closed in the pool: a transport's close may wait on the loop
        self._started = True
        loop = self.loop
        self.thread = loop.hold(self._holder) or self.thread
        loop.call(self._add)

    def _add(self, now: float) -> None:
        if self._finishing:  # the loop failed as it started: abandoned already
            return
        for bus in self.buses:
            self.loop.add(bus)
            self.loop.due(bus)

    def _loop_failed(self, error: Exception) -> None:
        """The loop itself failed (in its thread, as that ends; whoever started it): fatal for the fleet, which
        is abandoned unless its end was decided already."""
        self.thread = threading.current_thread()
        self.poller.supervisor.fail(THREAD_NAME, error)
        if not self._finishing:
            self._abandon()

    def _poke(self, bus: Bus) -> None:
        """Step ``bus`` at the loop's next turn (any thread): a job was queued, its lent work is over."""
        if not self._finishing:
            self.loop.due(bus)

    def wake(self) -> None:
        """Look at every bus again now (the poller stops); nothing once the fleet's end is decided."""
        if self._started:
            for bus in self.buses:
                self._poke(bus)

    def lent(self) -> list[threading.Thread]:
        """The pool's threads now (running jobs, opening or closing devices, the fleet's end)."""
        return self.pool.alive

    @property
    def driving(self) -> bool:
        """Between start and the end: a job queued now is run by the pool (or at the end)."""
        return self._started and not self._ended.is_set()

    @property
    def alive(self) -> bool:
        return self.driving or bool(self.pool.alive) or any(t.is_alive() for t in self._loop_threads())

    def _loop_threads(self) -> list[threading.Thread]:
        """The loop's thread this fleet ran on, once it no longer serves the loop (stopped by the last holder, or
        failed): the fleet's end waits for it. One still serving the loop for other holders is not waited for."""
        mine = self.thread
        return [mine] if mine.ident is not None and mine is not self.loop.thread else []

    def join(self, timeout: float | None = None) -> None:
        """Wait for the end: every bus shut down, the pool's threads, and the loop's thread the fleet ran on once
        it no longer serves the loop (it stopped with the fleet's end, or failed)."""
        deadline = None if timeout is None else time.monotonic() + timeout

        def left() -> float | None:
            return None if deadline is None else max(0.0, deadline - time.monotonic())

        if self._started and not self._ended.wait(left()):
            return
        for thread in self._loop_threads():
            if thread is not threading.current_thread():
                thread.join(left())
        for thread in self.pool.alive:
            thread.join(left())

    def own_thread(self) -> bool:
        """Whether the calling thread is one of the fleet's own (the loop, the pool): it must not wait for the
        end, which may wait for it."""
        return self._started and (self.loop.in_loop() or threading.current_thread() in self.pool.alive)

    # -- a bus's step, in the loop -------------------------------------------------------------------------------

    def serve(self, bus: Bus, now: float) -> None:
        """Advance the bus's poll and start the next (:meth:`_service`); an exception that is not the line's
        (``on_sample`` raised, a bug) is contained for this bus alone: counted and logged by the supervisor,
        its poll cancelled, its devices closed, the bus resumed after the backoff; the other buses go on."""
        if self._finishing or bus.handed_over:
            return
        if self.poller.stopping.is_set():
            self._stop_bus(bus)
        else:
            try:
                self._service(bus, now)
            except Exception as exc:
                worker = bus.worker
                pause = self.poller.supervisor.contain(worker.name, exc)
                self._stop_bus(bus)
                resume = self.poller.clock() + pause
                worker.restart(resume)
                bus.free_at = resume
        self._plan(bus)

    def _service(self, bus: Bus, now: float) -> None:
        """Advance the bus's poll; when it is over, start the next one that is due at once (the line's
        silence after the last answer is already behind it)."""
        clock = self.poller.clock
        while True:
            task = bus.task
            if task is not None:
                try:
                    task.advance(now)
                except Exception as exc:
                    self._defect(bus, task, exc)
                if not task.done:
                    return
                attempt, bus.task, bus.attempt = bus.attempt, None, None
                assert attempt is not None
                try:
                    result: PollResult | None = task.result()
                    error: StarterbusError | None = None
                except StarterbusError as exc:
                    result, error = None, bus.failure or exc
                bus.failure = None
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
                    ended = clock()
                    started = bus  # (its task read again, not as narrowed above: the one just started)
                    following = started.task if self._next(bus, now, lend=False) else None
                    if following:
                        try:
                            following.advance(clock())
                        except Exception as exc:
                            self._defect(bus, following, exc)
                    self._end(bus, attempt, result, error, ended)
                    if following and not following.done:
                        return
                    now = clock()
                    continue
                self._end(bus, attempt, result, error)
                now = clock()
            if not self._next(bus, now):
                return

    @staticmethod
    def _defect(bus: Bus, task: PollTask, exc: Exception) -> None:
        """``task.advance`` raised what it should not: a defect in a transport fails its poll instead of stopping
        every bus."""
        task.cancel()
        bus.failure = TransportError(f"{bus.worker.bus.name}: the poll failed: {type(exc).__name__}: {exc}")

    def _next(self, bus: Bus, now: float, lend: bool = True) -> bool:
        """Between polls: lend the bus for queued jobs (or devices to close), lend it to open the device due
        next, or start the poll that is due (True); jobs and polls alike only once the bus's ``delay`` after
        the last poll is over. ``lend=False``: the last poll's bookkeeping is still to come, jobs wait for it
        (a job would use its device meanwhile)."""
        worker = bus.worker
        if worker.lent or bus.free_at > now:
            return False
        if worker.jobs or worker.dropped:
            if lend:
                self._lend(bus, self._jobs, bus)
            return False
        if worker.finished or self.poller.stopping.is_set():
            return False
        due, index = worker.next_due(now)
        if due > now:
            return False
        runtime = worker.devices[index]
        if runtime.device is None and runtime.open_error is None:
            if lend:
                self._lend(bus, worker.open_for_poll, runtime)
            return False
        runtime = worker.take(due)
        attempt = bus.attempt = worker.begin(runtime)
        try:
            device = worker.prepare(attempt)
            if attempt.probe:
                with worker.policy(attempt, device):
                    task = device.transport.start_poll(attempt.points, runtime.status)
            else:  # (the transport's own rules: no context to enter)
                task = device.transport.start_poll(attempt.points, runtime.status)
        except StarterbusError as exc:
            bus.attempt = None
            self._end(bus, attempt, None, exc)
            return True
        if task is None:
            self._hand_over(bus, runtime)
            return False
        task.on_progress = bus.poke
        bus.task = task
        return True

    def _plan(self, bus: Bus) -> None:
        """When the bus is next stepped without news, whether it is over; the fleet ends once every bus is."""
        if bus.task is not None:  # the poll's descriptor and time (the usual case: a poll follows a poll)
            bus.fd, bus.deadline = bus.task.fd, bus.task.wake_at
            return
        worker, now = bus.worker, self.poller.clock()
        over = False
        if bus.handed_over:
            over = True
        elif worker.lent:
            bus.next_at = INF  # the lent work steps it when it gives the bus back
        elif self.poller.stopping.is_set() or (worker.finished and not worker.jobs):
            bus.next_at, over = INF, True
        elif bus.free_at > now:
            bus.next_at = bus.free_at
        elif worker.jobs or worker.dropped or worker.finished:
            bus.next_at = now
        else:
            bus.next_at = worker.next_due(now)[0]
        bus.fd, bus.deadline = -1, bus.next_at
        if over is not bus.over:
            bus.over = over
            if over and all(b.over for b in self.buses):
                self._finish()

    def _lend(self, bus: Bus, work: Callable[..., object], *args: object) -> None:
        """``work(*args)`` in the pool, the bus's polls held until it is done."""
        worker = bus.worker
        worker.lent = True

        def run() -> None:
            try:
                work(*args)
            finally:
                worker.lent = False
                self._poke(bus)

        self.pool.run(run, f"jobs-{worker.bus.name}")

    def _jobs(self, bus: Bus) -> None:
        bus.worker.close_dropped()
        bus.worker.run_jobs()

    def _end(
        self,
        bus: Bus,
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

    def _hand_over(self, bus: Bus, runtime: DeviceRuntime) -> None:
        """This bus polls by blocking: it gets a thread of its own, starting with ``runtime``'s poll."""
        bus.handed_over = True
        bus.attempt = None
        worker = bus.worker
        worker.deferred = False
        worker.notify = worker.wake.set
        worker.thread = self.poller.supervisor.thread(worker.name, worker.run, runtime)
        worker.thread.start()

    def _stop_bus(self, bus: Bus) -> None:
        """Cancel the bus's poll in flight (what it sent is counted); no other starts."""
        if bus.task is not None:
            bus.task.cancel()
            bus.task = None
        if bus.attempt is not None:
            bus.worker.abandon(bus.attempt)
            bus.attempt = None

    # -- the end -----------------------------------------------------------------------------------------------

    def _finish(self) -> None:
        """Every bus is over (in the loop): they leave it, and the pool shuts them down."""
        self._finishing = True
        for bus in self.buses:
            self.loop.remove(bus)
        self.pool.run(self._shut_down, "fleet-end")

    def _shut_down(self) -> None:
        """The jobs queued until now run, the devices are closed; then the fleet lets go of the loop's thread
        (stopped if it was the last holder)."""
        try:
            for bus in self.buses:
                if not bus.handed_over:
                    bus.worker.shut_down()
        finally:
            self.loop.unhold(self._holder)
            self._ended.set()

    def _abandon(self) -> None:
        """The loop failed (in its thread, after it ended): every poll cancelled, the lent work waited for, the
        buses shut down here."""
        self._finishing = True
        loop = self.loop
        for bus in self.buses:
            self._stop_bus(bus)

        def remove(now: float) -> None:
            for bus in self.buses:
                loop.remove(bus)

        loop.call(remove)
        loop.try_turn()  # made now, unless another thread leads (it makes it)
        self.pool.drain()
        self._shut_down()
