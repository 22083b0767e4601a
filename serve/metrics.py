"""Which Sparkplug metrics a node and each fleet device publish, typed, aliased and described from the profile.

A device publishes its decoded status (``Status/*``), its configured measurements (``Measurements/<key>``) and
parameters (``Parameters/<key>``), and offers ``Device Control/Start|Stop|Reset`` for DCMD; the outcome of the
last command, refusals included, is ``Device Control/Last Command``, and ``Device Control/Command Count`` goes +1
with every outcome (so a repeated identical outcome is still seen). Each measurement or parameter carries the
profile's unit, range, resolution, English and Chinese names as metric properties in the DBIRTH; an enum (and
the fault code) its labels as the property set ``enum`` (code -> {``en``, ``zh``}); ``writable`` says what the
fleet file's ``remote`` table lets a host write or command. Values polled from the device carry the Sparkplug
``Quality`` property (192 good, 0 bad: not read in the device's last good poll).
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from dataclasses import dataclass, field

from starterbus.core.model import Label, PointDef
from starterbus.core.profile import Profile
from starterbus.core.status import Command
from starterbus.fleet.config import DeviceConfig
from starterbus.fleet.poller import Sample
from starterbus.serve.schema import DataType

Scalar = float | int | bool | str
#: a metric property: key, type and value; a PROPERTYSET's value is a tuple of properties
Property = tuple[str, DataType, "Scalar | tuple[Property, ...]"]

QUALITY = "Quality"  # Sparkplug's property: Int32, 192 good, 0 bad, 500 stale
GOOD, BAD = 192, 0

REBIRTH = "Node Control/Rebirth"
BDSEQ = "bdSeq"
LAST_COMMAND = "Device Control/Last Command"
REFUSED = "Device Control/Commands Refused"
COMMAND_COUNT = "Device Control/Command Count"
COMMAND_METRICS = {
    "Device Control/Start": Command.START,
    "Device Control/Stop": Command.SOFT_STOP,
    "Device Control/Reset": Command.FAULT_RESET,
}
NODE_DEVICES_ONLINE = "Node Info/Devices Online"
NODE_DROPPED = "Node Info/Buffered Messages Dropped"
NODE_REFUSED = "Node Info/Commands Refused"
NODE_LAST_COMMAND = "Node Info/Last Command"
NODE_COMMAND_COUNT = "Node Info/Command Count"

_STATUS_METRICS: tuple[tuple[str, DataType], ...] = (
    ("Status/State", DataType.STRING),
    ("Status/Fault", DataType.BOOLEAN),
    ("Status/Fault Code", DataType.INT32),
    ("Status/Fault Text", DataType.STRING),
    ("Status/Ready", DataType.BOOLEAN),
    ("Status/Bus Control", DataType.BOOLEAN),
    ("Status/Starting", DataType.BOOLEAN),
    ("Status/Running", DataType.BOOLEAN),
    ("Status/Stopping", DataType.BOOLEAN),
)


_POINT_PREFIXES = ("Measurements/", "Parameters/")


@dataclass(frozen=True, slots=True)
class MetricDef:
    name: str
    datatype: DataType
    alias: int | None
    properties: tuple[Property, ...] = ()
    deadband: float = 0.0  # a numeric change smaller than this is not reported (0: every change)
    point: PointDef | None = None  # the measurement or parameter behind it
    command: Command | None = None  # a Device Control metric: true in a DCMD asks for this command
    writable: bool = False  # by a DCMD: the profile allows it and so does the fleet file's remote table
    polled: bool = False  # a value read from the device: it carries the Quality property


@dataclass(slots=True)
class MetricSet:
    """The metrics of the node or of one device, found by name or by alias."""

    defs: list[MetricDef]
    by_name: dict[str, MetricDef] = field(default_factory=dict)
    by_alias: dict[int, MetricDef] = field(default_factory=dict)
    #: point key -> the metrics a sample's value of it sets (``Measurements/<key>``, ``Parameters/<key>``) and
    #: whether each is integral: :func:`sample_values` looks each value up once, without building names
    by_point: dict[str, tuple[tuple[str, bool], ...]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.by_name = {d.name: d for d in self.defs}
        self.by_alias = {d.alias: d for d in self.defs if d.alias is not None}
        by_point: dict[str, list[tuple[str, bool]]] = {}
        for prefix in _POINT_PREFIXES:
            for d in self.defs:
                if d.name.startswith(prefix):
                    by_point.setdefault(d.name[len(prefix) :], []).append((d.name, d.datatype is DataType.INT32))
        self.by_point = {key: tuple(names) for key, names in by_point.items()}


class Aliases:
    """Aliases unique across the node and its devices (payloads-alias-uniqueness), stable over rebirths."""

    def __init__(self) -> None:
        self._next = 1

    def take(self) -> int:
        alias, self._next = self._next, self._next + 1
        return alias


def node_metrics(aliases: Aliases) -> MetricSet:
    return MetricSet(
        [
            MetricDef(BDSEQ, DataType.INT64, None),
            MetricDef(REBIRTH, DataType.BOOLEAN, None),  # never aliased (rebirth-name-aliases)
            MetricDef(NODE_DEVICES_ONLINE, DataType.INT32, aliases.take()),
            MetricDef(NODE_DROPPED, DataType.INT64, aliases.take()),
            MetricDef(NODE_REFUSED, DataType.INT64, aliases.take()),
            MetricDef(NODE_LAST_COMMAND, DataType.STRING, aliases.take()),
            MetricDef(NODE_COMMAND_COUNT, DataType.INT64, aliases.take()),
        ]
    )


def enum_property(labels: Mapping[int, Label]) -> Property:
    """``enum``: code (decimal text) -> {``en``, ``zh``}, a PropertySet of PropertySets."""
    codes = tuple(
        (str(code), DataType.PROPERTYSET, (("en", DataType.STRING, label.en), ("zh", DataType.STRING, label.zh)))
        for code, label in sorted(labels.items())
    )
    return ("enum", DataType.PROPERTYSET, codes)


def _point_metric(prefix: str, point: PointDef, aliases: Aliases, deadband_steps: float, writable: bool) -> MetricDef:
    integral = point.enum is not None or point.scale == 1
    datatype = DataType.INT32 if integral else DataType.DOUBLE
    props: list[Property] = [
        ("engUnit", DataType.STRING, point.unit),
        ("engLow", DataType.DOUBLE, float(point.to_engineering(point.raw_min))),
        ("engHigh", DataType.DOUBLE, float(point.to_engineering(point.raw_max))),
        ("resolution", DataType.DOUBLE, float(point.scale)),
        ("nameEn", DataType.STRING, point.name_en),
        ("nameZh", DataType.STRING, point.name_zh),
        ("address", DataType.STRING, point.address),
        ("writable", DataType.BOOLEAN, writable),
    ]
    if point.enum is not None:
        props.append(enum_property(point.enum.labels))
    name = sys.intern(f"{prefix}/{point.key}")  # one string for every device's: less memory read per sample
    deadband = deadband_steps * point.scale
    return MetricDef(name, datatype, aliases.take(), tuple(props), deadband, point, writable=writable, polled=True)


def device_metrics(
    config: DeviceConfig,
    profile: Profile,
    aliases: Aliases,
    deadband_steps: float = 1.0,
    per_key: Mapping[str, float] | None = None,
) -> MetricSet:
    """``deadband_steps``: resolution steps a value must move to be reported; ``per_key`` overrides it by key."""
    per_key = per_key or {}
    remote = config.remote

    def point(prefix: str, key: str) -> MetricDef:
        p = profile.point(key)
        writable = p.writable and remote.allows_write(p.key)
        return _point_metric(prefix, p, aliases, per_key.get(p.key, deadband_steps), writable)

    faults = (enum_property(profile.faults.labels),)
    defs = [
        MetricDef(name, datatype, aliases.take(), faults if name == "Status/Fault Code" else (), polled=True)
        for name, datatype in _STATUS_METRICS
    ]
    defs += [point("Measurements", k) for k in config.measurements]
    defs += [point("Parameters", k) for k in config.parameters]
    for name, cmd in COMMAND_METRICS.items():
        allowed = remote.allows_command(cmd)
        props: tuple[Property, ...] = (("writable", DataType.BOOLEAN, allowed),)
        defs.append(MetricDef(name, DataType.BOOLEAN, aliases.take(), props, command=cmd, writable=allowed))
    defs += [
        MetricDef(LAST_COMMAND, DataType.STRING, aliases.take()),
        MetricDef(REFUSED, DataType.INT64, aliases.take()),
        MetricDef(COMMAND_COUNT, DataType.INT64, aliases.take()),
    ]
    return MetricSet(defs)


def sample_values(sample: Sample, metrics: MetricSet) -> dict[str, Scalar | None]:
    """The metric values one good poll tells (None: this path does not tell); empty for a failed poll."""
    status = sample.status
    if status is None:
        out: dict[str, Scalar | None] = {}
    else:
        out = {
            "Status/State": status.state.value,
            "Status/Fault": status.fault,
            "Status/Fault Code": status.fault_code or 0,
            "Status/Fault Text": status.fault_text or "",
            "Status/Ready": status.ready,
            "Status/Bus Control": status.bus_control,
            "Status/Starting": status.starting,
            "Status/Running": status.running,
            "Status/Stopping": status.stopping,
        }
    by_point = metrics.by_point
    for key, value in sample.values.items():
        for name, integral in by_point.get(key, ()):
            out[name] = round(value.value) if integral else float(value.value)
    return out


#: a deadband is met by a change of the band less this (a change of exactly the band, after float arithmetic)
BAND_MET = 1 - 1e-9


def changed(defn: MetricDef, old: Scalar | None, new: Scalar | None) -> bool:
    """Report by exception: a numeric value outside the deadband, any other change. Equal values are never a
    change (``EdgeSession._device_data`` skips them without calling this)."""
    if type(new) is float and type(old) is float:  # the common case: numbers, without the isinstance calls
        pass
    elif old is None or new is None or isinstance(new, (bool, str)) or isinstance(old, (bool, str)):
        return old != new or (old is None) != (new is None)
    return abs(float(new) - float(old)) >= defn.deadband * BAND_MET and new != old


def initial_values() -> Mapping[str, Scalar | None]:
    """What a device's control metrics say before any command."""
    values: dict[str, Scalar | None] = {name: False for name in COMMAND_METRICS}
    values.update({LAST_COMMAND: "", REFUSED: 0, COMMAND_COUNT: 0})
    return values
