"""What a bus worker (:mod:`starterbus.fleet.bus_worker`) and the multiplexer (:mod:`starterbus.fleet.mux`) use
of the poller that runs them. :class:`~starterbus.fleet.poller.FleetPoller` is one; naming it here instead keeps
the arrows one way: the poller imports the workers, the workers import this."""

from __future__ import annotations

import random
import threading
from collections.abc import Callable
from typing import Protocol

from starterbus.core.supervision import Supervisor
from starterbus.fleet.config import FleetConfig
from starterbus.fleet.probing import ProbeSettings
from starterbus.fleet.sample import Sample


class PollContext(Protocol):
    config: FleetConfig
    supervisor: Supervisor
    clock: Callable[[], float]
    probing: ProbeSettings
    rng: random.Random
    rounds: int | None  # polling rounds per bus before it stops; None: until stopped
    stopping: threading.Event

    def emit(self, sample: Sample) -> None:
        """Hand a sample to the poller's ``on_sample``, one at a time."""
