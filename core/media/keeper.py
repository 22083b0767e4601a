"""Engines that need the time while no caller waits (a cyclic exchange whose peer has a watchdog): the
scheduler's own thread runs while at least one holds it (:func:`keep_running` / :func:`let_go`).

Each :func:`keep_running` is one :class:`Holder` of the loop's thread (``Scheduler.hold``), counted with the
others (fleets): the thread stops when the last holder of any kind lets go, never under another."""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

__all__ = ["KEEPER", "Holder", "Runnable", "keep_running", "let_go"]

#: the name of a :func:`keep_running` holder (``Scheduler.holders``)
KEEPER = "keep_running"


@dataclass(eq=False)
class Holder:
    """One who needs the loop's own thread to run (``Scheduler.hold``). ``on_failure(error)``: the loop itself
    failed (called in the loop's thread as it ends, after the loop was given up: callers lead again)."""

    name: str
    on_failure: Callable[[Exception], None] | None = None


class Runnable(Protocol):
    """What is needed of the scheduler (:class:`starterbus.core.Scheduler`)."""

    def hold(self, holder: Holder) -> object: ...
    def unhold(self, holder: Holder) -> None: ...


_kept: dict[Runnable, list[Holder]] = {}  # loop -> its keep_running holders
_lock = threading.Lock()


def keep_running(loop: Runnable) -> None:
    """The loop's own thread runs (started now if it does not) until this holder lets go (:func:`let_go`) and
    every other holder of it too."""
    holder = Holder(KEEPER)
    loop.hold(holder)
    with _lock:
        _kept.setdefault(loop, []).append(holder)


def let_go(loop: Runnable) -> None:
    """One holder of :func:`keep_running` fewer (the thread stops if it was the last holder of any kind)."""
    with _lock:
        held = _kept.get(loop)
        if not held:
            return
        holder = held.pop()
        if not held:
            del _kept[loop]
    loop.unhold(holder)
