"""The canopen transport passes starterbus's conformance kit, served by its own LocalNode simulator."""

from __future__ import annotations

import contextlib
import itertools
import os
from collections.abc import Iterator, Sequence

from starterbus_canopen.simulator import CanopenSimulator

from starterbus.core import SimulatedStarter
from starterbus.testing import TransportConformance

_channels = itertools.count()


class TestCanopen(TransportConformance):
    transport = "canopen"
    model = "example_canopen_starter"

    @contextlib.contextmanager
    def serve(self, starter: SimulatedStarter) -> Iterator[str]:
        with self.serve_units([starter]) as (url,):
            yield url

    @contextlib.contextmanager
    def serve_units(self, starters: Sequence[SimulatedStarter]) -> Iterator[list[str]]:
        channel = f"conformance-co-{os.getpid()}-{next(_channels)}"
        nodes = [5 + 5 * i for i in range(len(starters))]
        with CanopenSimulator(("virtual", channel), heartbeat_ms=0, event_timer=0.05) as sim:  # the nodes on one bus
            for starter, node in zip(starters, nodes, strict=True):
                sim.add_node(starter, node)
            yield [f"canopen://virtual/{channel}?node={node}&heartbeat=50" for node in nodes]
