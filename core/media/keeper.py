"""Engines that need the time while no caller waits (a cyclic exchange whose peer has a watchdog): the
scheduler's own thread runs while at least one holds it (:func:`keep_running` / :func:`let_go`)."""

from __future__ import annotations

import threading
from typing import Protocol

__all__ = ["Runnable", "keep_running", "let_go"]


class Runnable(Protocol):
    """What is needed of the scheduler (:class:`starterbus.core.Scheduler`)."""

    @property
    def running(self) -> bool: ...
    def start(self) -> object: ...
    def stop(self) -> object: ...


_kept: dict[int, int] = {}  # id(loop) -> holders
_started: set[int] = set()  # loops whose own thread a holder started
_lock = threading.Lock()


def keep_running(loop: Runnable) -> None:
    """The loop's own thread runs until every holder let go (:func:`let_go`). A thread started here is stopped
    by the last :func:`let_go`; one started by someone else (a fleet, a service) is left alone."""
    with _lock:
        _kept[id(loop)] = _kept.get(id(loop), 0) + 1
        start = _kept[id(loop)] == 1 and not loop.running
        if start:
            _started.add(id(loop))
    if start:
        loop.start()


def let_go(loop: Runnable) -> None:
    """One holder of :func:`keep_running` fewer."""
    with _lock:
        users = _kept.get(id(loop), 0) - 1
        if users > 0:
            _kept[id(loop)] = users
            return
        _kept.pop(id(loop), None)
        stop = id(loop) in _started
        _started.discard(id(loop))
    if stop:
        loop.stop()
