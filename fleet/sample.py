"""One poll of one device as the poller hands it to its sinks (table, JSON lines, CSV)."""

from __future__ import annotations

from dataclasses import dataclass

from starterbus.core.frozen_twin import twin
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


_SampleTwin = twin(Sample)


def polled(
    device: str,
    bus: str,
    model: str,
    time: float,
    online: bool,
    status: Status | None,
    values: dict[str, Value],
    error: str | None,
    errors: int,
    unreadable: tuple[str, ...],
    wire: TransportCounters | None,
    probe: bool,
) -> Sample:
    """``Sample(...)`` of every field, as a poller makes one each poll (no ``__init__``: core/frozen_twin.py)."""
    made = _SampleTwin()
    made.device, made.bus, made.model, made.time, made.online, made.status = device, bus, model, time, online, status
    made.values, made.error, made.errors, made.unreadable, made.wire, made.probe = (
        values, error, errors, unreadable, wire, probe
    )  # fmt: skip
    made.__class__ = Sample
    return made  # type: ignore[no-any-return]
