"""A CANopen poll as a :class:`~starterbus.core.PollTask` for the fleet's poller: no thread per bus.

A poll is written once as a generator of SDO requests (:data:`Steps`): it yields an
:class:`~starterbus_canopen.sdo.Upload` or :class:`~starterbus_canopen.sdo.Download`, is sent the transfer's
bytes (or thrown its error) and returns its result. :func:`drive` runs it blocking (the sync API: each transfer a
ticket on the scheduler, waited for as leader or follower; given to the engine in the caller's own thread while
the loop waits in the bus's own queue: ``CanDriver.submit_here``); :class:`SdoPoll` runs it
without blocking as the core's :class:`~starterbus.core.TicketPoll` (``on_progress`` in the fleet's loop; else a
turn of the scheduler, or a pipe of its own while another thread runs the loop: the loop's own thread, kept
running while a CANopen device is open for its heartbeat and TPDO times).
"""

from __future__ import annotations

import functools
from collections.abc import Generator
from typing import TypeVar

from starterbus.core import PollResult, TicketPoll, ToEngine, follow_steps
from starterbus_canopen.bus import CanBus
from starterbus_canopen.sdo import SdoEngine, SdoRequest

__all__ = ["STALL", "SdoPoll", "Steps", "drive", "transfer"]

T = TypeVar("T")

#: SDO requests out, the transfers' bytes in, a result at the end
Steps = Generator[SdoRequest, bytes, T]

#: the outer bound of a wait beyond the transfer's own timeout: only a stalled loop gets there
STALL = 30.0
#: a transfer given to the engine in the caller's thread is waited for on its future alone for twice its timeout
#: and this (its answer, or its timeout after a quiet period), then through the scheduler (which the caller leads
#: if the loop's own thread is gone)
FOLLOW = 0.1


def transfer(bus: CanBus, engine: SdoEngine, request: SdoRequest) -> bytes:
    """One SDO transfer, waited for (leading the loop while no other thread does); its bytes, or its error. The
    request is given to the engine in this thread while the loop waits in the bus's own queue
    (``CanDriver.submit_here``: the frame goes out without a thread hand-off), else through the loop."""
    loop, driver = bus.loop, bus.driver
    handoff = driver.submit_here(engine, request)
    try:
        # the loop's own thread ends it: wait for that alone (no lead to take meanwhile), up to twice the timeout
        # and a margin (its answer, or its timeout after a quiet period); else through the scheduler, which the
        # caller leads if no thread does
        if handoff is not None and loop.thread is not None and handoff.wait(request.timeout * 2 + FOLLOW):
            ticket = handoff.ticket
        else:
            future = handoff.follow() if handoff is not None else loop.submit(driver, ToEngine(engine, request))
            try:
                ticket = loop.wait(future, request.timeout + STALL, bus.sdo_what)
            except BaseException:
                if handoff is None and not future.cancel():
                    loop.call(lambda now: driver.cancel([future], now))
                raise
    except BaseException:  # a stalled loop, an interrupt: the ticket is withdrawn at the loop's next turn
        if handoff is not None:
            given = handoff.ticket
            loop.call(lambda now: driver.withdraw([given], now))
        raise
    data: bytes = ticket.outcome()
    return data


def drive(bus: CanBus, engine: SdoEngine, steps: Steps[T]) -> T:
    """Run ``steps`` to its end, each transfer waited for in turn (:func:`transfer`; the core's ``run_steps`` with
    the request given to the engine in this thread where it can be)."""
    return follow_steps(steps, lambda request: transfer(bus, engine, request))


class SdoPoll(TicketPoll[SdoRequest]):
    """The poll ``steps`` on ``engine``'s node of ``bus``, one transfer at a time."""

    def __init__(self, bus: CanBus, engine: SdoEngine, steps: Steps[PollResult]) -> None:
        wrap = functools.partial(ToEngine, engine)
        super().__init__(bus.loop, bus.driver, steps, where=bus.name, what="SDO transfer", wrap=wrap, stall=STALL)
        self.bus, self.engine = bus, engine
