"""What a recorded start is (:mod:`starterbus.ops.record` takes it, :mod:`starterbus.ops.plot` draws it): its
status reads with the phase currents, and the current limit in amperes."""

from __future__ import annotations

from dataclasses import dataclass, field

from starterbus.core.model import PointDef

PHASES = ("a", "b", "c")


@dataclass(frozen=True, slots=True)
class Point:
    """One status read: seconds since the start, wall time, state, fault code and the phase currents (A)."""

    t: float
    time: float
    state: str
    fault_code: int | None
    currents: dict[str, float]


@dataclass(slots=True)
class Recording:
    device: str
    model: str
    started: float  # wall time of the start (command sent, or first seen)
    points: list[Point] = field(default_factory=list)
    limit_a: float | None = None  # the current limit in A, when the parameters could be read
    rated_a: float | None = None
    commanded: bool = False
    ended: str = ""  # why the recording stopped
    failed: bool = False  # sampling ended on an error or Ctrl-C (``ended`` says which), not on the motor's state

    def state_at_end(self) -> str:
        return self.points[-1].state if self.points else "unknown"


def limit_in_amps(limit: PointDef, limit_value: float, rated_a: float) -> tuple[float, float]:
    """A current limit is a multiple of the rated current: in % (JJR5000, SSD1) or x In (JJR8000)."""
    factor = limit_value / 100.0 if limit.unit.strip() == "%" else limit_value
    return factor * rated_a, rated_a
