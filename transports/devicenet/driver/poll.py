"""A DeviceNet poll as a :class:`~starterbus.core.PollTask` for the fleet's multiplexer: no thread per bus.

The poll is written as a generator of the master's tickets (:class:`Steps`): it yields a request, is sent the
ticket's result (or thrown its error) and returns the :class:`~starterbus.core.PollResult`. The core's
:class:`~starterbus.core.TicketPoll` runs it on the master's engine of the bus's driver, one ticket at a time,
without blocking (``on_progress`` in the fleet's loop; else a turn of the scheduler, or a pipe of its own while
another thread leads: a master that keeps the loop's own thread for its polled I/O connection).
"""

from __future__ import annotations

import functools
from collections.abc import Generator
from typing import Any

from starterbus.core import PollResult, TicketPoll, ToEngine
from starterbus.transports.devicenet.driver.scanner import STALL, Scanner
from starterbus.transports.devicenet.master.requests import MasterRequest

__all__ = ["DeviceNetPoll", "Steps"]

#: a poll: requests out, their results in, the poll's result at the end
Steps = Generator[MasterRequest, Any, PollResult]


class DeviceNetPoll(TicketPoll[MasterRequest]):
    """The poll ``steps`` on ``scanner``'s bus, one ticket at a time."""

    def __init__(self, scanner: Scanner, steps: Steps) -> None:
        super().__init__(
            scanner.loop,
            scanner.driver,
            steps,
            where=scanner.where,
            wrap=functools.partial(ToEngine, scanner.engine),
            stall=STALL,
        )
        self.scanner = scanner
