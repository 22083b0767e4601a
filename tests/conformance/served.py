"""What a kit class's ``serve()`` remembers for its fault hook: each starter's simulator and its address there."""

from __future__ import annotations

from typing import Generic, TypeVar

from starterbus.core.simulator import SimulatedStarter

SimulatorT = TypeVar("SimulatorT")


class Served(Generic[SimulatorT]):
    """``note_served`` in ``serve()``, ``served_by`` in ``faults()`` (per test: pytest makes an instance for each)."""

    served: dict[int, tuple[SimulatorT, int]] | None = None  # id(starter) -> (simulator, address)

    def note_served(self, starter: SimulatedStarter, sim: SimulatorT, address: int) -> None:
        if self.served is None:
            self.served = {}
        self.served[id(starter)] = (sim, address)

    def served_by(self, starter: SimulatedStarter) -> tuple[SimulatorT, int]:
        assert self.served is not None and id(starter) in self.served, (
            "faults(starter) of a starter serve() did not serve"
        )
        return self.served[id(starter)]
