"""The driver of an engine whose peer is in this process: a function call per unit, no descriptor, deadlines only.

The peer (``exchange``) takes one unit the engine wrote and returns the unit it answers with, at once (a
simulated slave, a card's library call). The driver reads its clock after each call, so the reply is received
at the time it came (``receive(reply, now)``); a peer that raises fails that unit (``engine.refused``, with the
error made by ``error``: a :class:`StarterbusError` as it is, anything else a :class:`TransportError`).

Units that follow at once (an engine exchanging on demand, back to back) are written in one step, up to
:data:`BURST` of them and until a ticket ends, so a task of a few exchanges costs one turn of the scheduler but a
long one cannot starve the other drivers of the loop.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol, TypeVar

from starterbus.core.engine import Engine
from starterbus.core.errors import StarterbusError, TransportError
from starterbus.core.media.driver import Driver

__all__ = ["BURST", "LocalDriver", "LocalEngine"]

Req = TypeVar("Req")
Res = TypeVar("Res")
Unit = TypeVar("Unit")

#: units written in one step at most (the other drivers of the loop get their turn after them)
BURST = 16


class LocalEngine(Engine[Req, Res, Unit], Protocol[Req, Res, Unit]):
    """An engine on an in-process peer: told when the peer raised instead of answering a unit."""

    def refused(self, unit: Unit, error: StarterbusError, now: float) -> None:
        """The peer raised on ``unit``: that unit got no answer."""
        ...


E = TypeVar("E", bound=LocalEngine[Any, Any, Any])


def as_error(exc: Exception) -> StarterbusError:
    """A peer's exception as a starterbus error (a TransportError unless it already is one)."""
    if isinstance(exc, StarterbusError):
        return exc
    return TransportError(f"{type(exc).__name__}: {exc}")


class LocalDriver(Driver[E]):
    """An engine on an in-process peer. ``clock`` must be the clock of the scheduler that steps it."""

    def __init__(
        self,
        name: str,
        make_engine: Callable[[], E],
        exchange: Callable[[Any], Any],
        *,
        clock: Callable[[], float] = time.monotonic,
        error: Callable[[Exception], StarterbusError] = as_error,
    ) -> None:
        super().__init__(name, make_engine)
        self.exchange = exchange
        self.clock = clock
        self._error = error
        self.units = 0  # units written
        self.refusals = 0  # of which the peer raised on

    def step(self, now: float, ready: bool) -> None:
        engine = self.engine
        take = engine.take_completed
        due = engine.deadline
        for _ in range(BURST):
            if now >= due:
                engine.advance(now)
                done = take()
                if done:
                    self.complete(now, done)  # a batch that failed is withdrawn before its next request could go out
            out = engine.take_output(now)
            if not out:
                return
            now = self._give(out)
            done = take()
            if done:
                self.complete(now, done)
                return  # a ticket ended: its waiter may go on
            due = engine.deadline
            if due > now:
                return  # nothing more is due now

    def write(self, units: Sequence[Any], now: float) -> None:
        self._give(units)

    def _give(self, units: Sequence[Any]) -> float:
        """Give each unit to the peer and its answer to the engine, at the time it came; the time after the last."""
        engine, exchange, clock = self.engine, self.exchange, self.clock
        now = 0.0
        for unit in units:
            self.units += 1
            try:
                reply = exchange(unit)
            except Exception as exc:  # the peer's failure is this unit's, typed
                self.refusals += 1
                now = clock()
                engine.refused(unit, self._error(exc), now)
                continue
            now = clock()
            engine.receive(reply, now)
        return now
