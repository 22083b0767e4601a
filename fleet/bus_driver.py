"""One fleet bus as a driver of the process's scheduler (:class:`~starterbus.core.scheduler.Served`): the loop
waits on its poll's descriptor and deadline (or, between polls, on when it is next due) and steps it; the
multiplexer (:mod:`starterbus.fleet.mux`) says what a step does."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

from starterbus.core.engine import Ticket
from starterbus.core.errors import StarterbusError
from starterbus.core.polling import PollTask
from starterbus.fleet.bus_worker import BusWorker
from starterbus.fleet.device_poll import Attempt

__all__ = ["Bus"]


def _nothing(bus: Bus, now: float) -> None:
    pass


def _alone() -> None:
    pass


@dataclass(eq=False)
class Bus:
    """A bus, its poll under way, and where it stands between polls."""

    worker: BusWorker
    on_step: Callable[[Bus, float], None] = _nothing  # what a step does (the multiplexer's)
    task: PollTask | None = None
    attempt: Attempt | None = None
    free_at: float = 0.0  # the bus's ``delay`` after a poll
    failure: StarterbusError | None = None  # what went wrong where a task raised what it should not
    handed_over: bool = False  # to a thread of its own
    over: bool = False  # nothing left to do now (its rounds done, or the poller stopping)
    next_at: float = 0.0  # when to step it while no poll is under way
    # what the loop reads of every bus at every turn: plain attributes, set by the multiplexer after each step
    fd: int = -1  # the poll's descriptor (-1: none)
    deadline: float = 0.0  # the poll's ``wake_at``, or ``next_at`` between polls
    writing: bool = False
    poke: Callable[[], None] = _alone  # step it at the loop's next turn (the multiplexer's, from any thread)

    def __post_init__(self) -> None:
        self.name = self.worker.name

    def step(self, now: float, ready: bool) -> None:
        self.on_step(self, now)

    def crash(self, error: StarterbusError, now: float) -> None:
        """The loop saw the poll's line fail under it (a descriptor closed under the wait): the poll ends with
        ``error`` (the bus goes on)."""
        task = self.task
        if task is not None:
            task.cancel()
            self.failure = error
        self.on_step(self, now)

    # the rest of a driver's surface: a bus takes no requests of its own

    def submit(
        self, requests: Sequence[Any], now: float, futures: Sequence[Future[Any] | None]
    ) -> list[Ticket[Any, Any]]:
        raise TypeError(f"{self.name}: a fleet bus takes no requests")

    def withdraw(self, tickets: Sequence[Ticket[Any, Any]], now: float) -> None:
        """Nothing to withdraw: a bus hands out no tickets."""

    def cancel(self, futures: Sequence[Future[Any]], now: float) -> None:
        """Nothing to cancel: a bus hands out no tickets."""
