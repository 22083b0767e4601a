"""Decoded status, commands and the control/status words that every fieldbus of these devices shares.

The status word and control word layout (docs/manuals.md#1-common-model) is the same on Modbus and Profibus; DeviceNet
assemblies carry the same facts in other bits. Each transport turns what it receives into one :class:`Status`.
"""

from __future__ import annotations

import enum
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

from starterbus.core.frozen_twin import twin
from starterbus.core.model import Label, PointDef, Value
from starterbus.core.timestamps import iso_time


class Command(str, enum.Enum):
    """What a master can ask a soft starter to do."""

    START = "start"
    SOFT_STOP = "stop"
    FAULT_RESET = "reset"
    TAKE_BUS_CONTROL = "take-bus-control"
    RELEASE_BUS_CONTROL = "release-bus-control"


class MotorState(str, enum.Enum):
    """The one name of each motor state, shown as it is by every output (status, watch, poll table and CSV,
    JSON, history, Sparkplug ``Status/State``, the OPC UA ``StarterStateEnum``).

    ``ready`` and ``stopped`` are both an idle motor, but not the same state: ``ready`` is idle with status word
    bit 13 set ("ready to start": main circuit powered, start allowed); ``stopped`` is idle and not known to be
    ready: bit 13 clear (no mains, a start inhibit), or a path that does not report it (an input assembly,
    where ``Status.ready`` is None). A start from ``stopped`` may be refused by the starter.
    """

    FAULT = "fault"
    STARTING = "starting"
    RUNNING = "running"
    STOPPING = "stopping"
    READY = "ready"
    STOPPED = "stopped"
    UNKNOWN = "unknown"


# Control word bits (section 1).
CW_START = 1 << 0
CW_RESERVED_1 = 1 << 1
CW_RESET = 1 << 2
CW_BUS_CONTROL = 1 << 3

# Status word bits.
SW_FAULT_CODE_MASK = 0x003F
SW_STARTING = 1 << 8
SW_RUNNING = 1 << 9
SW_STOPPING = 1 << 10
SW_BIT12 = 1 << 12
SW_READY = 1 << 13
SW_BUS_CONTROL = 1 << 14
SW_FAULT = 1 << 15
SW_KNOWN_BITS = SW_FAULT_CODE_MASK | SW_STARTING | SW_RUNNING | SW_STOPPING | SW_READY | SW_BUS_CONTROL | SW_FAULT


@dataclass(frozen=True, slots=True)
class FaultTable:
    """A model's fault codes with their texts; unknown codes decode as "unknown fault N", never an error."""

    labels: Mapping[int, Label]

    def text(self, code: int) -> str:
        label = self.labels.get(code)
        return label.en if label is not None else f"unknown fault {code}"

    def label(self, code: int) -> Label:
        return self.labels.get(code) or Label(f"unknown fault {code}", f"未知故障 {code}")


@dataclass(frozen=True, slots=True)
class Status:
    """A decoded device status, whichever transport it came through.

    ``None`` means "this path does not tell" (e.g. ``ready`` over DeviceNet), never "false".
    ``raw`` keeps the words or bytes it was decoded from; ``unknown_bits`` the set bits no manual explains.
    """

    fault: bool
    fault_code: int | None
    fault_text: str | None
    starting: bool
    running: bool
    stopping: bool
    ready: bool | None = None
    bus_control: bool | None = None
    warning: bool | None = None
    at_reference: bool | None = None
    mains_voltage: bool | None = None
    currents: Mapping[str, Value] = field(default_factory=dict)  # "a", "b", "c" -> Value (with resolution)
    raw: Mapping[str, int] = field(default_factory=dict)
    unknown_bits: int = 0
    source: str = ""
    timestamp: float = field(default_factory=time.time)

    @property
    def state(self) -> MotorState:
        if self.fault:
            return MotorState.FAULT
        if self.starting:
            return MotorState.STARTING
        if self.stopping:
            return MotorState.STOPPING
        if self.running:
            return MotorState.RUNNING
        if self.ready:
            return MotorState.READY
        return MotorState.STOPPED

    def as_json(self) -> dict[str, object]:
        return {
            "state": self.state.value,
            "fault": self.fault,
            "fault_code": self.fault_code,
            "fault_text": self.fault_text,
            "ready": self.ready,
            "starting": self.starting,
            "running": self.running,
            "stopping": self.stopping,
            "bus_control": self.bus_control,
            "warning": self.warning,
            "at_reference": self.at_reference,
            "mains_voltage": self.mains_voltage,
            "currents": {k: v.as_json() for k, v in self.currents.items()},
            "raw": {k: f"0x{v:04X}" for k, v in self.raw.items()},
            "unknown_bits": f"0x{self.unknown_bits:04X}",
            "source": self.source,
            "timestamp": iso_time(self.timestamp),
        }


def decode_status_word(
    word: int,
    faults: FaultTable,
    *,
    bit12_is_mains_voltage: bool = False,
    currents: Mapping[str, Value] | None = None,
    source: str = "",
    extra_raw: Mapping[str, int] | None = None,
) -> Status:
    """Decode the 16-bit status word of section 1 (Modbus register 1, Profibus ZSW)."""
    return _decoded(word, faults, bit12_is_mains_voltage, dict(currents or {}), source, extra_raw)


_StatusTwin = twin(Status)
_now = time.time  # Status's default timestamp
#: status word -> what it says but the fault's text (words repeat: a poller decodes each device's every round)
_PARTS: tuple[dict[int, tuple[bool, int | None, bool, bool, bool, bool, bool, bool | None, int]], ...] = ({}, {})
_PARTS_KEPT = 4096  # per dictionary (bit 12 a mains voltage or not), emptied when full


def _decoded(
    word: int, faults: FaultTable, bit12: bool, currents: dict[str, Value], source: str, extra: Mapping[str, int] | None
) -> Status:
    """:func:`decode_status_word`, ``currents`` taken as they are."""
    kept = _PARTS[1] if bit12 else _PARTS[0]
    parts = kept.get(word) if type(word) is int else None
    if parts is None:
        if not 0 <= word <= 0xFFFF:
            raise ValueError(f"status word {word!r} is not a 16-bit value")
        fault = bool(word & SW_FAULT)
        known = SW_KNOWN_BITS | (SW_BIT12 if bit12 else 0)
        parts = (
            fault,
            word & SW_FAULT_CODE_MASK if fault else None,
            bool(word & SW_STARTING),
            bool(word & SW_RUNNING),
            bool(word & SW_STOPPING),
            bool(word & SW_READY),
            bool(word & SW_BUS_CONTROL),
            bool(word & SW_BIT12) if bit12 else None,
            word & ~known & 0xFFFF,
        )
        if type(word) is int:
            if len(kept) >= _PARTS_KEPT:
                kept.clear()
            kept[word] = parts
    made = _StatusTwin()  # (no __init__: see frozen_twin.py)
    (
        made.fault, made.fault_code, made.starting, made.running, made.stopping, made.ready, made.bus_control,
        made.mains_voltage, made.unknown_bits,
    ) = parts  # fmt: skip
    made.fault_text = faults.text(parts[1]) if parts[0] else None  # type: ignore[arg-type]
    made.warning = made.at_reference = None
    made.currents = currents
    made.raw = {"status_word": word, **extra} if extra else {"status_word": word}
    made.source = source
    made.timestamp = _now()
    made.__class__ = Status
    return made  # type: ignore[no-any-return]


#: the keys of :attr:`Status.currents`, in the order of the profile's ``phase_currents`` role
PHASE_NAMES = ("a", "b", "c")


class StatusBits(Protocol):
    """How a model reads bit 12 of its status word (a profile's ``control`` traits)."""

    @property
    def bit12_is_mains_voltage(self) -> bool: ...


class StatusModel(Protocol):
    """What decoding a status needs of a device model; a :class:`~starterbus.core.profile.Profile` is one (the
    profile loader sits above this module, so it is named by what it offers)."""

    @property
    def faults(self) -> FaultTable: ...

    @property
    def control(self) -> StatusBits: ...

    def phase_currents(self) -> Sequence[PointDef]: ...


def status_with_currents(
    profile: StatusModel,
    word: int,
    currents: Sequence[int],
    *,
    source: str = "",
    scale: float | None = None,
    current_source: str | None = None,
    extra_raw: Mapping[str, int] | None = None,
) -> Status:
    """The status from a status word and the raw phase currents a transport read (L1 first; fewer is fine).

    Each current is scaled by its profile point (or by ``scale``, the resolution of the transport's path);
    ``current_source`` (default ``source``) tags the current values.
    """
    tag = source if current_source is None else current_source
    values = {
        name: Value.from_raw(point, raw, scale, tag)
        for name, point, raw in zip(PHASE_NAMES, profile.phase_currents(), currents, strict=False)
    }
    return _decoded(word, profile.faults, profile.control.bit12_is_mains_voltage, values, source, extra_raw)


def encode_status_word(
    *,
    fault_code: int | None,
    starting: bool,
    running: bool,
    stopping: bool,
    ready: bool,
    bus_control: bool,
    mains_voltage: bool = False,
) -> int:
    """The inverse of :func:`decode_status_word`, used by simulators."""
    word = 0
    if fault_code is not None:
        word |= SW_FAULT | (fault_code & SW_FAULT_CODE_MASK)
    if starting:
        word |= SW_STARTING
    if running:
        word |= SW_RUNNING
    if stopping:
        word |= SW_STOPPING
    if mains_voltage:
        word |= SW_BIT12
    if ready:
        word |= SW_READY
    if bus_control:
        word |= SW_BUS_CONTROL
    return word


@dataclass(slots=True)
class ControlWordState:
    """The master's side of the control word: which bits it holds, and what each command turns them into.

    The run bit and the bus-control bit are levels the master keeps; fault reset is a pulse. ``apply`` returns
    the words to send in order (a reset is the word with bit 2 set, then the word without it).
    """

    bus_control: bool = True
    run: bool = False

    @property
    def word(self) -> int:
        return (CW_BUS_CONTROL if self.bus_control else 0) | (CW_START if self.run else 0)

    def apply(self, command: Command) -> list[int]:
        if command is Command.START:
            self.run = True
            return [self.word]
        if command is Command.SOFT_STOP:
            self.run = False
            return [self.word]
        if command is Command.FAULT_RESET:
            self.run = False
            return [self.word | CW_RESET, self.word]
        if command is Command.TAKE_BUS_CONTROL:
            self.bus_control = True
            return [self.word]
        if command is Command.RELEASE_BUS_CONTROL:
            self.bus_control = False
            self.run = False
            return [self.word]
        raise ValueError(f"unknown command {command!r}")


def describe_control_word(word: int) -> list[str]:
    """Names of the bits set in a control word (for decoders)."""
    names = [
        "start" if word & CW_START else "soft stop",
    ]
    if word & CW_RESET:
        names.append("fault reset")
    if word & CW_BUS_CONTROL:
        names.append("bus control")
    reserved = word & ~(CW_START | CW_RESET | CW_BUS_CONTROL) & 0xFFFF
    if reserved:
        names.append(f"reserved bits 0x{reserved:04X}")
    return names
