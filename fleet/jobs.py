"""The jobs (commands, writes) queued for one bus, run by whoever drives it between polls
(:meth:`FleetPoller.submit <starterbus.fleet.poller.FleetPoller.submit>`)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from starterbus.core.device import Device

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
