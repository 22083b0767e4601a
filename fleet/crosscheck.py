"""Cross-checking one device through several transports: the same facts, each at its own resolution.

Two readings of a value agree when they differ by no more than the coarser of their resolutions (a DeviceNet
current in whole amperes agrees with 23.5 A from Modbus if it reads 23 or 24). Status flags agree when every
path that reports the flag reports the same; a path that does not report it (``None``) is not counted.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from starterbus.core.device import Device, open_device
from starterbus.core.errors import StarterbusError, UnsupportedOperationError
from starterbus.core.model import Kind, PointDef, Value
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.status import SW_BUS_CONTROL, Status
from starterbus.core.transport import Capability

STATUS_FIELDS = (
    "fault",
    "fault_code",
    "ready",
    "starting",
    "running",
    "stopping",
    "bus_control",
    "warning",
    "at_reference",
)
#: shown but not compared: each master path sets the control word's bus-control bit itself, so every path
#: may honestly see a different value (a DeviceNet scanner always holds it, a Modbus reader never writes it)
PATH_DEPENDENT = frozenset({"bus_control"})


@dataclass
class PathReading:
    url: str
    transport: str = ""
    status: Status | None = None
    values: dict[str, Value] = field(default_factory=dict)
    unsupported: set[str] = field(default_factory=set)
    error: str | None = None


@dataclass(frozen=True, slots=True)
class Row:
    what: str  # key, or "status.<field>", or "current.<phase>"
    readings: tuple[str | None, ...]  # per path, text; None = not available on that path
    agree: bool | None  # None: fewer than two paths report it


@dataclass
class CrossCheckReport:
    model: str
    paths: list[PathReading]
    rows: list[Row]

    @property
    def ok(self) -> bool:
        return all(p.error is None for p in self.paths) and all(r.agree is not False for r in self.rows)

    @property
    def compared(self) -> int:
        return sum(1 for r in self.rows if r.agree is not None)

    def as_json(self) -> dict[str, object]:
        return {
            "model": self.model,
            "ok": self.ok,
            "paths": [
                {
                    "url": p.url,
                    "transport": p.transport,
                    "error": p.error,
                    "unsupported": sorted(p.unsupported),
                }
                for p in self.paths
            ],
            "rows": [{"what": r.what, "readings": list(r.readings), "agree": r.agree} for r in self.rows],
        }


def values_agree(values: Sequence[Value], ignore_bits: int = 0) -> bool:
    """Equal within the coarser resolution of the two (for enums and bit words: exactly equal but ``ignore_bits``)."""
    for a in values:
        for b in values:
            if a.point.enum is not None or a.point.bits:
                if (a.raw ^ b.raw) & ~ignore_bits:
                    return False
            elif abs(float(a.value) - float(b.value)) > max(a.resolution, b.resolution) + 1e-9:
                return False
    return True


def _read_path(device: Device, points: Sequence[PointDef], reading: PathReading) -> None:
    caps = device.capabilities
    if Capability.STATUS in caps:
        reading.status = device.status()
    for point in points:
        needed = Capability.READ_PARAMETERS if point.kind is Kind.PARAMETER else Capability.READ_MEASUREMENTS
        if needed not in caps:
            reading.unsupported.add(point.key)
            continue
        try:
            reading.values.update(device.read(point))
        except UnsupportedOperationError:
            reading.unsupported.add(point.key)


def crosscheck(
    urls: Sequence[str],
    model: str | Profile,
    keys: Sequence[str] | None = None,
    *,
    include_parameters: bool = True,
) -> CrossCheckReport:
    profile = model if isinstance(model, Profile) else get_profile(model)
    if keys:
        points = [profile.point(k) for k in keys]
    else:
        points = [p for p in profile.measurements if p.key not in (profile.roles.get("control_word"),)]
        if include_parameters:
            points += profile.parameters
    paths: list[PathReading] = []
    for url in urls:
        reading = PathReading(url)
        paths.append(reading)
        try:
            device = open_device(url, profile)
            reading.transport = device.transport.name
            with device:
                _read_path(device, points, reading)
        except StarterbusError as exc:
            reading.error = str(exc)
    rows: list[Row] = []
    for point in points:
        found = [p.values.get(point.key) for p in paths]
        present = [v for v in found if v is not None]
        ignore = SW_BUS_CONTROL if point.key == profile.roles.get("status_word") else 0
        agree = values_agree(present, ignore) if len(present) >= 2 else None
        rows.append(Row(point.key, tuple(v.text() if v else None for v in found), agree))
    for name in STATUS_FIELDS:
        found_flags = [getattr(p.status, name) if p.status is not None else None for p in paths]
        present_flags = [f for f in found_flags if f is not None]
        agree = len(set(present_flags)) == 1 if len(present_flags) >= 2 and name not in PATH_DEPENDENT else None
        rows.append(Row(f"status.{name}", tuple(None if f is None else str(f) for f in found_flags), agree))
    for phase in ("a", "b", "c"):
        currents = [p.status.currents.get(phase) if p.status is not None else None for p in paths]
        present_currents = [c for c in currents if c is not None]
        if not present_currents:
            continue
        agree = values_agree(present_currents) if len(present_currents) >= 2 else None
        rows.append(Row(f"status.current_{phase}", tuple(c.text() if c else None for c in currents), agree))
    return CrossCheckReport(profile.name, paths, rows)
