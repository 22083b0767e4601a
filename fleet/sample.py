"""One poll of one device as the poller hands it to its sinks (table, JSON lines, CSV)."""

from __future__ import annotations

from dataclasses import dataclass

from starterbus.core.model import Value
from starterbus.core.status import Status
from starterbus.core.timestamps import iso_time
from starterbus.core.transport import TransportCounters


@dataclass(frozen=True, slots=True)
class Sample:
    """One poll of one device."""

    device: str
    bus: str
    model: str
    time: float  # wall clock, seconds since the epoch
    online: bool
    status: Status | None
    values: dict[str, Value]
    error: str | None
    errors: int  # errors of this device so far
    unreadable: tuple[str, ...] = ()  # configured keys this device's transport cannot read
    wire: TransportCounters | None = None  # what this poll put on the wire (None: the transport does not count)
    probe: bool = False  # a probe of an offline device (one attempt, short timeout)

    def as_json(self) -> dict[str, object]:
        return {
            "device": self.device,
            "bus": self.bus,
            "model": self.model,
            "time": iso_time(self.time),
            "online": self.online,
            "status": self.status.as_json() if self.status else None,
            "values": {
                k: {
                    "value": v.value,
                    "unit": v.unit,
                    "resolution": v.resolution,
                    "raw": v.raw,
                    "label": v.label.en if v.label else None,
                }
                for k, v in self.values.items()
            },
            "error": self.error,
            "errors": self.errors,
            "unreadable": list(self.unreadable),
            "probe": self.probe,
            "wire": self.wire.as_json() if self.wire is not None else None,
        }
