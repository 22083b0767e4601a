"""A CANopen poll as a :class:`~starterbus.core.PollTask` for the fleet's poller: no thread per bus.

A poll is written once as a generator of SDO requests (:data:`Steps`): it yields an
:class:`~starterbus_canopen.sdo.Upload` or :class:`~starterbus_canopen.sdo.Download`, is sent the transfer's
bytes (or thrown its error) and returns its result. :func:`drive` runs it blocking (the sync API: each transfer a
ticket on the scheduler, waited for as leader or follower, the core's ``run_steps``); :class:`SdoPoll` runs it
without blocking as the core's :class:`~starterbus.core.TicketPoll` (``on_progress`` in the fleet's loop; else a
turn of the scheduler, or a pipe of its own while another thread runs the loop: the loop's own thread, kept
running while a CANopen device is open for its heartbeat and TPDO times).
"""

from __future__ import annotations

import functools
from collections.abc import Generator
from typing import TypeVar

from starterbus.core import PollResult, TicketPoll, ToEngine, run_steps, wait_ticket
from starterbus_canopen.bus import CanBus
from starterbus_canopen.sdo import SdoEngine, SdoRequest

__all__ = ["STALL", "SdoPoll", "Steps", "drive", "transfer"]

T = TypeVar("T")

#: SDO requests out, the transfers' bytes in, a result at the end
Steps = Generator[SdoRequest, bytes, T]

#: the outer bound of a wait beyond the transfer's own timeout: only a stalled loop gets there
STALL = 30.0


def transfer(bus: CanBus, engine: SdoEngine, request: SdoRequest) -> bytes:
    """One SDO transfer, waited for (leading the loop while no other thread does); its bytes, or its error."""
    wrap = functools.partial(ToEngine, engine)
    ticket = wait_ticket(bus.loop, bus.driver, request, f"{bus.name}: SDO", wrap=wrap, stall=STALL)
    data: bytes = ticket.outcome()
    return data


def drive(bus: CanBus, engine: SdoEngine, steps: Steps[T]) -> T:
    """Run ``steps`` to its end, each transfer waited for in turn."""
    wrap = functools.partial(ToEngine, engine)
    return run_steps(bus.loop, bus.driver, steps, f"{bus.name}: SDO", wrap=wrap, stall=STALL)


class SdoPoll(TicketPoll[SdoRequest]):
    """The poll ``steps`` on ``engine``'s node of ``bus``, one transfer at a time."""

    def __init__(self, bus: CanBus, engine: SdoEngine, steps: Steps[PollResult]) -> None:
        wrap = functools.partial(ToEngine, engine)
        super().__init__(bus.loop, bus.driver, steps, where=bus.name, what="SDO transfer", wrap=wrap, stall=STALL)
        self.bus, self.engine = bus, engine
