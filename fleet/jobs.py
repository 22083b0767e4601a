"""The jobs (commands, writes) queued for one bus, run by whoever drives it between polls
(:meth:`FleetPoller.submit <starterbus.fleet.poller.FleetPoller.submit>`), and the small pool of threads that runs
them for the buses on the scheduler (:func:`job_pool`)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from starterbus.core.device import Device
from starterbus.core.supervision import Supervisor
from starterbus.core.worker_pool import WorkerPool

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


def job_pool(supervisor: Supervisor, size: int = POOL_SIZE) -> WorkerPool:
    """The threads shared by every bus of a fleet for what may block: jobs (commands, writes) and opening or
    closing devices (``Transport.open``/``close`` may wait on the scheduler, which the loop's own thread must
    not). Work runs in the order given, at most ``size`` at once; a thread starts when work comes while fewer
    than ``size`` run, and ends when no work is left. While it runs a piece of work, a thread has that work's
    name. Work that raises is the supervisor's: fatal, under the work's name (the pool goes on: the fleet's end
    runs in it)."""
    return WorkerPool(POOL_THREAD, size, on_error=supervisor.fail)
