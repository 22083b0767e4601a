"""What one bus worker put on its line: the transports' wire counters added up, and how busy the line was."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from starterbus.core.transport import TransportCounters


@dataclass
class LineStats:
    """Totals of one bus since its worker started.

    ``wire`` adds up every poll's and job's :class:`TransportCounters` (requests with retries, timeouts, bytes,
    wire time); ``wire.busy_time`` is the time the worker spent inside its transports (holding the line).
    ``utilisation`` is that time over the elapsed time; ``wire_utilisation`` the time the frames and silences
    occupied the wire over the elapsed time (0 for transports that do not count bytes).
    """

    bus: str
    started: float
    stopped: float | None = None
    wire: TransportCounters = field(default_factory=TransportCounters)
    polls: int = 0
    probes: int = 0
    elapsed: float = 0.0  # set by :meth:`snapshot`

    def snapshot(self, now: float) -> LineStats:
        end = self.stopped if self.stopped is not None else now
        return dataclasses.replace(self, wire=self.wire.copy(), elapsed=max(0.0, end - self.started))

    @property
    def utilisation(self) -> float:
        return self.wire.busy_time / self.elapsed if self.elapsed > 0 else 0.0

    @property
    def wire_utilisation(self) -> float:
        return self.wire.wire_time / self.elapsed if self.elapsed > 0 else 0.0

    def as_json(self) -> dict[str, object]:
        return {
            "bus": self.bus,
            "elapsed": round(self.elapsed, 3),
            "polls": self.polls,
            "probes": self.probes,
            "utilisation": round(self.utilisation, 4),
            "wire_utilisation": round(self.wire_utilisation, 4),
            **self.wire.as_json(),
        }
