"""The driver of an in-process peer (a function call per unit) with the toy engine: the caller drives the loop
(no thread), a peer that raises fails that unit with a typed error, and one step writes at most BURST units."""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence

import pytest

from starterbus.core.engine import Ticket, TicketState
from starterbus.core.errors import StarterbusError, TransportError
from starterbus.core.media.local import BURST, LocalDriver
from starterbus.core.scheduler import Scheduler
from starterbus.tests.engine.toy import ToyEngine, ToyPeer


class LocalToy(ToyEngine):
    """The toy engine told when its peer raised: the unit's transaction fails at once."""

    def refused(self, unit: bytes, error: StarterbusError, now: float) -> None:
        self.broken = None
        for ident, (ticket, _) in list(self._sent.items()):
            if ident == unit[1]:
                del self._sent[ident]
                ticket.failed(error, now)
                self._done.append(ticket)


def toy_peer(unit: bytes) -> bytes:
    if unit.endswith(b"boom"):
        raise OSError("the peer fell over")
    return b"".join(ToyPeer().replies(unit))


def test_the_caller_drives_an_in_process_peer_without_a_thread() -> None:
    loop = Scheduler()
    driver: LocalDriver[LocalToy] = LocalDriver("toy", LocalToy, toy_peer, clock=loop.clock)
    loop.wait(loop.call(lambda now: loop.add(driver)), 5, "add")
    threads = threading.active_count()
    (ticket,) = loop.run(driver, [b"abc"], 5, "ask")
    assert ticket.outcome() == b"ABC" and driver.units == 1 and threading.active_count() == threads


def test_a_peer_that_raises_fails_that_unit_typed() -> None:
    loop = Scheduler()
    driver: LocalDriver[LocalToy] = LocalDriver("toy", LocalToy, toy_peer, clock=loop.clock)
    loop.wait(loop.call(lambda now: loop.add(driver)), 5, "add")
    (ticket,) = loop.run(driver, [b"boom"], 5, "ask")
    assert ticket.state is TicketState.FAILED and isinstance(ticket.error, TransportError)
    assert "OSError: the peer fell over" in str(ticket.error) and driver.refusals == 1
    (again,) = loop.run(driver, [b"ok"], 5, "ask")
    assert again.outcome() == b"OK"  # the driver goes on


class Chatty:
    """Always has a unit to write (an engine exchanging back to back); its one ticket never ends."""

    deadline = -math.inf

    def __init__(self) -> None:
        self.written = 0

    def submit(self, request: int, now: float) -> Ticket[int, int]:
        return Ticket(request)

    def cancel(self, ticket: Ticket[int, int], now: float) -> None: ...
    def receive(self, data: int | None, now: float) -> None: ...
    def refused(self, unit: int, error: StarterbusError, now: float) -> None: ...
    def advance(self, now: float) -> None: ...

    def take_output(self, now: float) -> Sequence[int]:
        self.written += 1
        return [self.written]

    def take_completed(self) -> list[Ticket[int, int]]:
        return []


@pytest.mark.parametrize("steps", [1, 3])
def test_one_step_writes_at_most_a_burst(steps: int) -> None:
    driver: LocalDriver[Chatty] = LocalDriver("chatty", Chatty, lambda unit: unit)
    for _ in range(steps):
        driver.step(0.0, False)
    assert driver.units == steps * BURST
