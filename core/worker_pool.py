"""A few threads for work that may block, started as work comes and ended when it is done: the asyncio edge's
pool (:func:`starterbus.aio.edge_pool`) and a fleet's job pool (:func:`starterbus.fleet.jobs.job_pool`).

Not :class:`concurrent.futures.ThreadPoolExecutor`, whose threads live until ``shutdown()`` and are joined at
the interpreter's exit: the edge's pool belongs to the process and is never shut down (its threads end after
``linger`` seconds without work, and a job blocked on a dead line does not hold up the exit: daemon threads);
a fleet's pool runs the fleet's own end (a shutdown from inside it) and leaves no thread once its work is done
(the thread counts of tests/fleet/test_thread_count.py and test_mux*.py). A thread also takes the name of the
work it runs (``jobs-BUS``), and work that raises goes to ``on_error`` (a fleet's supervisor: fatal).
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from typing import TypeVar

log = logging.getLogger(__name__)

T = TypeVar("T")


def _log_error(name: str, exc: Exception) -> None:
    log.error("%s: work failed", name, exc_info=exc)


class WorkerPool:
    """At most ``size`` daemon threads named ``name``: one starts when work comes and no idle thread is left to
    take it, and ends after ``linger`` seconds without work (0: as soon as none is queued). Work starts in the
    order given."""

    def __init__(
        self,
        name: str,
        size: int,
        *,
        linger: float = 0.0,
        on_error: Callable[[str, Exception], object] = _log_error,
    ) -> None:
        self.name = name
        self.size = max(1, size)
        self.linger = linger
        self.on_error = on_error
        self._work: deque[tuple[str | None, Callable[[], object]]] = deque()
        self._lock = threading.Lock()
        self._more = threading.Condition(self._lock)  # work queued (idle threads wait on it)
        self._quiet = threading.Condition(self._lock)  # a piece of work or a thread ended (drain waits on it)
        self._alive = 0  # threads started that have not decided to end
        self._idle = 0  # of them, waiting for work
        self._running = 0  # pieces of work under way
        self._threads: list[threading.Thread] = []
        self.started = 0  # threads started since the pool was made

    def run(self, work: Callable[[], object], name: str | None = None) -> None:
        """Run ``work()`` in a pool thread (from any thread), the thread named ``name`` meanwhile if given. An
        exception is ``on_error(name, exc)``'s (the pool's name if the work has none); the pool goes on."""
        with self._lock:
            self._work.append((name, work))
            start = self._idle < len(self._work) and self._alive < self.size
            if start:
                self._alive += 1
                self.started += 1
                thread = threading.Thread(target=self._serve, name=self.name, daemon=True)
                self._threads = [*(t for t in self._threads if t.is_alive()), thread]
            else:
                self._more.notify()
        if start:
            thread.start()

    def submit(self, fn: Callable[[], T], name: str | None = None) -> Future[T]:
        """``fn()`` in a pool thread; its result (or exception) in the future (withdrawn if cancelled before)."""
        future: Future[T] = Future()
        self.run(functools.partial(settle, future, fn), name)
        return future

    def drain(self, timeout: float | None = None) -> bool:
        """Wait until no work is queued or under way (False: not within ``timeout``)."""
        with self._lock:
            return self._quiet.wait_for(lambda: not self._work and not self._running, timeout)

    @property
    def alive(self) -> list[threading.Thread]:
        """The pool's threads now (working, idle, or ending)."""
        with self._lock:
            threads = list(self._threads)
        return [t for t in threads if t.is_alive()]

    def _serve(self) -> None:
        me = threading.current_thread()
        while True:
            with self._lock:
                give_up = time.monotonic() + self.linger
                while not self._work:
                    remaining = give_up - time.monotonic()
                    if remaining <= 0:
                        self._alive -= 1
                        self._quiet.notify_all()
                        return
                    self._idle += 1
                    self._more.wait(remaining)
                    self._idle -= 1
                name, work = self._work.popleft()
                self._running += 1
            if name is not None:
                me.name = name
            try:
                work()
            except Exception as exc:  # the machinery around a job (a job's own error is its future's)
                self.on_error(name or self.name, exc)
            finally:
                me.name = self.name
                with self._lock:
                    self._running -= 1
                    self._quiet.notify_all()


def settle(future: Future[T], fn: Callable[[], T]) -> None:
    """Run ``fn`` for ``future`` unless it was cancelled before it started (then nothing runs)."""
    if future.set_running_or_notify_cancel():
        try:
            future.set_result(fn())
        except BaseException as exc:  # the awaiting task's to see, typed as raised
            future.set_exception(exc)
