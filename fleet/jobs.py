"""The jobs (commands, writes) queued for one bus, run by whoever drives it between polls
(:meth:`FleetPoller.submit <starterbus.fleet.poller.FleetPoller.submit>`), and the small pool of threads that runs
them for the buses on the scheduler (:class:`JobPool`)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from starterbus.core.device import Device
from starterbus.core.supervision import Supervisor

#: a job for one device of a bus: its name, what to do with it, the future of the result
Job = tuple[str, Callable[[Device], Any], Future[Any]]


class JobQueue:
    """Jobs in the order queued; closed when the bus shuts down, so that none is queued where nobody would run
    it (the bus's last run of its jobs comes after :meth:`close`)."""

    def __init__(self) -> None:
        self._jobs: list[Job] = []
        self.lock = threading.RLock()  # also held by whoever runs a job after the end, one at a time
        self.closed = False

    def __bool__(self) -> bool:
        return bool(self._jobs)

    def put(self, job: Job) -> bool:
        """Queue ``job``; False once closed."""
        with self.lock:
            if self.closed:
                return False
            self._jobs.append(job)
            return True

    def pop(self) -> Job | None:
        with self.lock:
            return self._jobs.pop(0) if self._jobs else None

    def close(self) -> None:
        with self.lock:
            self.closed = True


#: threads of a fleet's job pool at most, whatever the number of buses
POOL_SIZE = 4
#: the name of a pool thread between two pieces of work (it takes the name of the work it runs: ``jobs-BUS``)
POOL_THREAD = "fleet-jobs"


class JobPool:
    """A few threads shared by every bus of a fleet for what may block: jobs (commands, writes) and opening or
    closing devices (``Transport.open``/``close`` may wait on the scheduler, which the loop's own thread must
    not). Work runs in the order given, at most ``size`` at once; a thread starts when work comes while fewer
    than ``size`` run, and ends when no work is left. While it runs a piece of work, a thread has that work's
    name. Work that raises is the supervisor's: fatal, under the work's name (the pool goes on: the fleet's end
    runs in it)."""

    def __init__(self, supervisor: Supervisor, size: int = POOL_SIZE) -> None:
        self.supervisor = supervisor
        self.size = max(1, size)
        self._work: list[tuple[str, Callable[[], object]]] = []
        self._cond = threading.Condition()
        self._busy = 0  # threads started that have not decided to end
        self.threads: list[threading.Thread] = []

    def run(self, name: str, work: Callable[[], object]) -> None:
        """Run ``work()`` in a pool thread named ``name`` meanwhile (any thread)."""
        with self._cond:
            self._work.append((name, work))
            start = self._busy < self.size  # else a thread that has not decided to end takes it
            if start:
                thread = self.supervisor.thread(POOL_THREAD, self._serve)
                self.threads = [*(t for t in self.threads if t.is_alive()), thread]
                self._busy += 1
        if start:
            thread.start()

    def _serve(self) -> None:
        me = threading.current_thread()
        while True:
            with self._cond:
                if not self._work:
                    self._busy -= 1
                    self._cond.notify_all()
                    return
                name, work = self._work.pop(0)
            me.name = name
            try:
                work()
            except Exception as exc:  # the machinery around a job failed (a job's own error is its future's)
                self.supervisor.fail(name, exc)
            finally:
                me.name = POOL_THREAD

    def drain(self, timeout: float | None = None) -> bool:
        """Wait until no work is queued or running (False: not within ``timeout``)."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._work and self._busy == 0, timeout)

    @property
    def alive(self) -> list[threading.Thread]:
        return [t for t in self.threads if t.is_alive()]
