"""A station's poll as a :class:`PollTask` for the fleet: its requests submitted to the station's driver once, then
turns of the scheduler without blocking, so a PKW bus needs no thread of its own (docs/engine.md, step 6).

Driven in the manner of ``MbapPoll``: when the fleet gives ``on_progress`` (the fleet on the scheduler: advance
runs in the loop's thread), the futures' done callbacks call it and the task waits for nothing else; otherwise
(a poller outside the loop) each advance runs one turn of the scheduler (``try_turn``), and looks again after
:data:`LOOK_AGAIN` while another thread leads.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Future
from typing import Any

from starterbus.core import PollResult, PollTask, StarterbusError, TicketState, TransportError
from starterbus.transports.profibus_pkw.driver.link import STALL, CyclicLink
from starterbus.transports.profibus_pkw.master.station import StationRequest, StationTicket

__all__ = ["LOOK_AGAIN", "StationPoll"]

#: how soon a poll looks again while another thread runs the loop (that thread serves the poll meanwhile)
LOOK_AGAIN = 0.001


class StationPoll(PollTask):
    """``requests`` on the link's station as one batch (the first to fail withdraws the others); ``finish`` makes
    the poll's result from their tickets; ``bound``: the requests' own time limits (a stall margin is added)."""

    on_progress: Callable[[], None] | None = None

    def __init__(
        self,
        link: CyclicLink,
        requests: Sequence[StationRequest],
        finish: Callable[[list[StationTicket]], PollResult],
        bound: float,
    ) -> None:
        self.link, self.requests, self.finish = link, requests, finish
        self.bound = bound + STALL
        self._futures: list[Future[Any]] | None = None
        self._tickets: list[StationTicket] = []
        self._result: PollResult | None = None
        self._error: StarterbusError | None = None
        self._until = 0.0  # the outer bound, set when the requests are submitted

    def advance(self, now: float) -> None:
        if self.done:
            return
        loop, driver = self.link.loop, self.link.driver
        if self._futures is None:
            self._futures = loop.submit_all(driver, self.requests)
            self._until = now + self.bound
            progress = self.on_progress
            if progress is not None:
                for future in self._futures:
                    future.add_done_callback(lambda _: progress())
        if self.on_progress is not None:
            self.fd, self.wake_at = -1, self._until
        elif loop.try_turn():
            self.fd, wake_at = self.link.waits_on()
            self.wake_at = min(wake_at, self._until)
        else:
            self.fd, self.wake_at = -1, now + LOOK_AGAIN
        futures = self._futures
        tickets = self._tickets
        while len(tickets) < len(futures) and futures[len(tickets)].done():
            index = len(tickets)
            ticket: StationTicket = futures[index].result()
            tickets.append(ticket)
            if ticket.state is not TicketState.DONE:
                self._end(ticket.error or TransportError(f"{driver.name}: poll withdrawn"), futures[index + 1 :])
                return
        if len(tickets) == len(futures):
            try:
                self._result = self.finish(tickets)
            except StarterbusError as exc:
                self._error = exc
            self.done = True
        elif now >= self._until:  # every request has a time limit of its own: only a stalled loop gets here
            stalled = f"{driver.name}: the poll's exchanges did not end within {self.bound:g} s: the loop stalled"
            self._end(TransportError(stalled), futures[len(tickets) :])

    def _end(self, error: StarterbusError, rest: Sequence[Future[Any]]) -> None:
        self._error = error
        self.done = True
        if rest:
            loop, driver = self.link.loop, self.link.driver
            for future in rest:
                future.cancel()  # not yet submitted: never will be
            loop.call(lambda now: driver.cancel(rest, now))
            if self.on_progress is None:
                loop.try_turn()  # the withdrawal made now, unless another thread leads (it makes it)

    def result(self) -> PollResult:
        if self._error is not None:
            raise self._error
        if self._result is None:
            raise TransportError(f"{self.link.driver.name}: the poll was cancelled")
        return self._result

    def cancel(self) -> None:
        if not self.done:
            self._end(TransportError(f"{self.link.driver.name}: the poll was cancelled"), self._futures or [])
