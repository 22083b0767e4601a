"""Supervision of a long-running service's threads and asyncio tasks: no worker dies quietly.

Every worker of ``poll``, ``serve`` and ``opcua`` runs under one :class:`Supervisor`, with one of two outcomes
for an exception nobody expected (a bug, a library failing in a new way):

- **contained** (``restart=True``, or :meth:`Supervisor.contain` where a worker catches it itself): logged once,
  in one line with the cause and where it was raised, counted per worker (``failures``, for metrics), and the
  worker goes on after a backoff (0.5 s, doubling up to 30 s; from the start again once it ran a minute
  without failing);
- **fatal** (the default): logged and counted the same way, then the whole service stops: ``failure`` holds a
  :class:`ServiceFailed` naming the worker and the cause in one line, every :meth:`Supervisor.on_fatal`
  callback runs (the command's stop), and the command exits non-zero once it has shut down.

A requested stop (a signal, ``--duration``) is no failure: the command exits 0 (130 after Ctrl-C).
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
import traceback
from collections.abc import Callable, Coroutine
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from starterbus.core.errors import StarterbusError

log = logging.getLogger("starterbus.service")

_PACKAGE = Path(__file__).resolve().parent.parent


class ServiceFailed(StarterbusError):
    """A worker of a long-running service failed and the service stopped (the worker and the cause, one line;
    an error starterbus raised on purpose, already one line naming what is wrong, is said as it is)."""

    def __init__(self, worker: str, cause: BaseException) -> None:
        self.worker = worker
        if isinstance(cause, StarterbusError):
            super().__init__(str(cause))
        else:
            super().__init__(f"{worker} failed: {describe(cause)}; the service stopped")


def describe(exc: BaseException) -> str:
    """``ValueError: boom (at fleet/device_poll.py:211 in end)``: the exception and the innermost frame of its
    traceback (a path inside the package is shown relative to it); an error starterbus raises on purpose is its
    own one-line message."""
    if isinstance(exc, StarterbusError):
        return str(exc)
    text = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    frames = traceback.extract_tb(exc.__traceback__) if exc.__traceback__ is not None else []
    if frames:
        last = frames[-1]
        where = Path(last.filename)
        try:
            shown = str(where.resolve().relative_to(_PACKAGE))
        except ValueError:
            shown = where.name
        text += f" (at {shown}:{last.lineno} in {last.name})"
    return text


@dataclass(frozen=True)
class Backoff:
    """Pauses before a contained worker goes on: ``first``, doubling per failure in a row, at most ``longest``;
    a worker that ran ``calm`` seconds since its last failure starts from ``first`` again."""

    first: float = 0.5
    longest: float = 30.0
    calm: float = 60.0

    def delay(self, in_a_row: int) -> float:
        return float(min(self.longest, self.first * 2 ** max(0, min(in_a_row - 1, 30))))


class Supervisor:
    """The workers of one service: their failures counted, contained ones paced, a fatal one stopping it all."""

    def __init__(self, backoff: Backoff | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.backoff = backoff or Backoff()
        self.clock = clock
        self.failures: dict[str, int] = {}  # worker name -> unexpected exceptions (contained and fatal)
        self.failure: ServiceFailed | None = None  # the first fatal one
        self.stopping = threading.Event()  # set by a fatal failure
        self._in_a_row: dict[str, tuple[int, float]] = {}  # worker -> (failures in a row, time of the last)
        self._callbacks: list[Callable[[ServiceFailed], None]] = []
        self._lock = threading.Lock()

    # -- outcomes ----------------------------------------------------------------------------------------------

    def contain(self, worker: str, exc: BaseException) -> float:
        """``worker`` survives ``exc``: logged, counted; returns how long it pauses before going on."""
        now = self.clock()
        with self._lock:
            self.failures[worker] = self.failures.get(worker, 0) + 1
            count, last = self._in_a_row.get(worker, (0, now))
            count = 1 if count and now - last >= self.backoff.calm else count + 1
            self._in_a_row[worker] = (count, now)
            total = self.failures[worker]
        delay = self.backoff.delay(count)
        log.error("%s: %s; going on in %.3g s (failure %d)", worker, describe(exc), delay, total)
        log.debug("%s: the traceback", worker, exc_info=exc)
        return delay

    def fail(self, worker: str, exc: BaseException) -> ServiceFailed:
        """``exc`` stops the service: counted, logged, the callbacks told (only the first failure is kept)."""
        failure = exc if isinstance(exc, ServiceFailed) else ServiceFailed(worker, exc)
        if failure is not exc:
            failure.__cause__ = exc
        with self._lock:
            if failure is not exc:  # a ServiceFailed passing through was counted where it happened
                self.failures[worker] = self.failures.get(worker, 0) + 1
            first = self.failure is None
            if first:
                self.failure = failure
            callbacks = list(self._callbacks)
        if not first:
            if failure is not exc:  # (the failure itself passing through another worker is no news)
                log.error("%s: %s (while the service was stopping)", worker, describe(exc))
            return failure
        log.debug("%s", failure, exc_info=exc)  # whoever runs the service reports it, in one line (check())
        self.stopping.set()
        for callback in callbacks:
            try:
                callback(failure)
            except Exception as error:  # one callback failing must not keep the others from stopping things
                log.error("stopping after %s: %s", worker, describe(error))
        return failure

    def on_fatal(self, callback: Callable[[ServiceFailed], None]) -> None:
        """Call ``callback(failure)`` on the first fatal failure (at once if there was one already)."""
        with self._lock:
            failure = self.failure
            if failure is None:
                self._callbacks.append(callback)
        if failure is not None:
            callback(failure)

    def check(self) -> None:
        """Raise the fatal failure, if there was one (after the service shut down: the command then exits 1)."""
        if self.failure is not None:
            raise self.failure

    @property
    def total_failures(self) -> int:
        with self._lock:
            return sum(self.failures.values())

    # -- threads -----------------------------------------------------------------------------------------------

    def thread(
        self,
        name: str,
        target: Callable[..., object],
        *args: object,
        restart: bool = False,
        until: threading.Event | None = None,
    ) -> threading.Thread:
        """A daemon thread (not started) running ``target(*args)`` under supervision. ``restart``: an exception
        is contained and ``target`` runs again after the backoff, unless ``until`` (or a fatal failure) is set
        meanwhile; else it is fatal. A normal return ends the thread."""

        def run() -> None:
            while True:
                try:
                    target(*args)
                    return
                except Exception as exc:
                    if not restart:
                        self.fail(name, exc)
                        return
                    delay = self.contain(name, exc)
                stop = until or self.stopping
                if stop.wait(delay) or self.stopping.is_set():
                    return

        return threading.Thread(target=run, name=name, daemon=True)

    # -- asyncio tasks -----------------------------------------------------------------------------------------

    def task(
        self,
        name: str,
        make: Callable[[], Coroutine[Any, Any, None]],
        *,
        restart: bool = False,
    ) -> asyncio.Task[None]:
        """An asyncio task running ``make()`` under supervision (on the running loop). ``restart``: contained,
        a new ``make()`` after the backoff; else fatal: the failure is recorded and the task raises
        :class:`ServiceFailed` (whoever awaits it sees one line), or the error itself if starterbus raised it on
        purpose (a :class:`StarterbusError` is already one line). Cancellation passes through."""

        async def run() -> None:
            while True:
                try:
                    await make()
                    return
                except asyncio.CancelledError:
                    raise
                except Exception as exc:
                    if not restart or isinstance(exc, ServiceFailed):
                        failure = self.fail(name, exc)
                        if failure is exc or isinstance(exc, StarterbusError):
                            raise
                        raise failure from exc
                    delay = self.contain(name, exc)
                await asyncio.sleep(delay)

        return asyncio.get_running_loop().create_task(run(), name=name)


__all__ = ["Backoff", "ServiceFailed", "Supervisor", "describe"]
