"""The protocol-neutral model: parameter/measurement definitions and the values read from them.

A :class:`PointDef` describes one 16-bit word of a device (a parameter or a measurement) with its raw range,
scale, unit, enum and its address on every protocol. Transports move raw integers; conversion to and from
engineering units happens here, once, for every transport.
"""

from __future__ import annotations

import enum
import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from starterbus.core.address_space import space_of
from starterbus.core.entry import alternative_reading, convert_unit, split_quantity
from starterbus.core.errors import ValidationError
from starterbus.core.frozen_twin import twin
from starterbus.core.scaling import SCALED
from starterbus.core.scaling import decimals as _decimals
from starterbus.core.scaling import engineering as _engineering


class Kind(str, enum.Enum):
    PARAMETER = "parameter"
    MEASUREMENT = "measurement"


class Access(str, enum.Enum):
    READ = "r"
    READ_WRITE = "rw"

    @property
    def writable(self) -> bool:
        return self is Access.READ_WRITE


class Certainty(str, enum.Enum):
    """Where a code, scale, default or address comes from."""

    PRINTED = "printed"  # printed in the manual
    INFERRED = "inferred"  # deduced from what is printed (print order, a worked example)
    ASSUMED = "assumed"  # chosen by the profile's author; the manual says nothing


@dataclass(frozen=True, slots=True)
class Provenance:
    """A certainty and, unless printed, why: a phrase that reads after the certainty ("inferred from ...")."""

    certainty: Certainty = Certainty.PRINTED
    why: str = ""

    @property
    def printed(self) -> bool:
        return self.certainty is Certainty.PRINTED

    def text(self) -> str:
        return f"{self.certainty.value} {self.why}".rstrip()

    def as_json(self) -> dict[str, str]:
        return {"certainty": self.certainty.value, "why": self.why}


PRINTED = Provenance()


@dataclass(frozen=True, slots=True)
class Label:
    """A text in English and in the manual's Chinese, and other spellings a user may type."""

    en: str
    zh: str = ""
    aliases: tuple[str, ...] = ()

    def __str__(self) -> str:
        return self.en

    def both(self) -> str:
        return f"{self.en} / {self.zh}" if self.zh and self.zh != self.en else self.en


@dataclass(frozen=True, slots=True)
class EnumTable:
    """A format code of the manual (F1, F2, ...): raw value -> label, and where each code comes from."""

    name: str
    labels: Mapping[int, Label]
    sources: Mapping[int, Provenance] = field(default_factory=dict)  # code -> provenance (absent: printed)

    def label(self, raw: int) -> Label | None:
        return self.labels.get(raw)

    def provenance(self, raw: int) -> Provenance:
        return self.sources.get(raw, PRINTED)

    def lookup(self, text: str) -> int | None:
        """Raw value for a label given in either language or as an alias (case-insensitive), or None."""
        wanted = text.strip().casefold()
        for raw, label in self.labels.items():
            if wanted in (label.en.casefold(), label.zh.casefold(), *(a.casefold() for a in label.aliases)):
                return raw
        return None

    def choices(self, lo: int = -0x8000, hi: int = 0xFFFF) -> str:
        """``0 = current limit / 限流, 1 = voltage ramp / 电压`` (codes within lo..hi)."""
        return ", ".join(f"{k} = {v.both()}" for k, v in sorted(self.labels.items()) if lo <= k <= hi)


class AddressTable(dict[str, Any]):
    """A point's addresses: address space -> address. Also looked up by the name of a transport that speaks the
    space (``addresses["modbus-rtu"]`` is the ``modbus`` address), as code written before address spaces does."""

    __slots__ = ()

    def __init__(self, items: Mapping[str, Any] = MappingProxyType({})) -> None:
        super().__init__((space_of(name), address) for name, address in items.items())

    def __missing__(self, name: str) -> Any:
        space = space_of(name)
        if space != name and dict.__contains__(self, space):
            return dict.__getitem__(self, space)
        raise KeyError(name)

    def get(self, name: str, default: Any = None) -> Any:
        if dict.__contains__(self, name):
            return dict.__getitem__(self, name)
        space = space_of(name)
        return dict.get(self, space, default) if space != name else default

    def __contains__(self, name: object) -> bool:
        return dict.__contains__(self, name) or (isinstance(name, str) and dict.__contains__(self, space_of(name)))


@dataclass(frozen=True, slots=True)
class PointDef:
    """One parameter or measurement of a device model."""

    key: str
    kind: Kind
    address: str  # the manual's own notation: "0x0103", "p7", "m3"
    name_zh: str
    name_en: str
    raw_min: int
    raw_max: int
    scale: float = 1.0
    unit: str = ""
    enum: EnumTable | None = None
    access: Access = Access.READ
    default: int | None = None
    bits: bool = False
    #: address space (``starterbus.core.address_space``) -> this point's address in it, as its parser made it
    addresses: Mapping[str, Any] = field(default_factory=AddressTable)
    note: str = ""
    scale_source: Provenance = PRINTED
    default_source: Provenance = Provenance(Certainty.ASSUMED)
    address_source: Provenance = PRINTED
    #: only these raw values are documented as writable (None: any value in range / in the enum)
    writable_values: frozenset[int] | None = None
    writable_why: str = ""

    @property
    def writable(self) -> bool:
        return self.kind is Kind.PARAMETER and self.access.writable

    @property
    def scale_assumed(self) -> bool:
        return not self.scale_source.printed

    def __post_init__(self) -> None:
        if type(self.addresses) is not AddressTable:
            object.__setattr__(self, "addresses", AddressTable(self.addresses))

    def address_for(self, transport: str) -> Any:
        """This point's address in an address space (its name, or the name of a transport that speaks it), or
        None."""
        return self.addresses.get(transport)

    def uncertainty(self, raw: int) -> str | None:
        """None when the address, the scale and (for enum points) the code ``raw`` are printed in the manual.

        Otherwise one line naming the key, the raw code and why, e.g. "p15 motor_overload_class: code 1
        (class 20) is inferred from print order, not printed in the manual".
        """
        reasons = []
        if not self.address_source.printed:
            reasons.append(f"its address {self.address} is {self.address_source.text()}")
        if self.enum is not None:
            label = self.enum.label(raw)
            if label is None:
                reasons.append(f"code {raw} is not in the manual's table {self.enum.name}")
            elif not (source := self.enum.provenance(raw)).printed:
                reasons.append(f"code {raw} ({label.en}) is {source.text()}")
        elif not self.scale_source.printed:
            step = f"x{self.scale:g} {self.unit}".rstrip()
            reasons.append(f"the scale {step} (raw {raw} = {self._shown(raw)}) is {self.scale_source.text()}")
        if not reasons:
            return None
        return f"{self.address} {self.key}: {'; '.join(reasons)}, not printed in the manual"

    # -- conversion ---------------------------------------------------------------------------------------

    def to_engineering(self, raw: int, scale: float | None = None) -> float | int:
        """Raw word -> engineering value (``scale`` overrides the profile's, for transports with other resolution)."""
        return _engineering(raw, self.scale if scale is None else scale)

    def _shown(self, raw: int) -> str:
        return f"{self.to_engineering(raw)} {self.unit}".rstrip()

    def to_raw(self, value: float | int | str) -> int:
        """Engineering value, value with its unit ("350%", "30s") or enum label -> raw word, validated.

        Raises :class:`ValidationError` naming the key and the value; nothing is rounded silently.
        """
        if isinstance(value, str):
            raw = self._parse_text(value)
        else:
            number = _finite(value)
            if number is None:
                raise ValidationError(f"{self.key}: {value!r} is not a number")
            raw = self._from_engineering(number, f"{value} {self.unit}".rstrip(), bare=True)
        self.check_raw(raw)
        return raw

    def check_range(self, raw: int) -> None:
        """Raise :class:`ValidationError` if a raw value is outside the range or the enum."""
        if not self.raw_min <= raw <= self.raw_max:
            lo, hi = self.to_engineering(self.raw_min), self.to_engineering(self.raw_max)
            raise ValidationError(
                f"{self.key} ({self.address}): {self._shown(raw)} is out of range {lo}..{hi} {self.unit}".rstrip()
            )
        if self.enum is not None and raw not in self.enum.labels:
            raise ValidationError(
                f"{self.key} ({self.address}): {raw} is not one of {self.enum.choices(self.raw_min, self.raw_max)}"
            )

    def check_raw(self, raw: int) -> None:
        """:meth:`check_range`, and for a write: only the values the manual documents as writable."""
        self.check_range(raw)
        if self.writable_values is not None and raw not in self.writable_values:
            allowed = ", ".join(str(v) for v in sorted(self.writable_values))
            why = f" ({self.writable_why})" if self.writable_why else ""
            raise ValidationError(
                f"{self.key} ({self.address}): only {allowed} is documented as writable{why}; {raw} is refused"
            )

    def _from_engineering(self, number: float, shown: str, bare: bool = False) -> int:
        exact = number / self.scale
        if not math.isfinite(exact) or abs(exact) > 1e12:
            raise ValidationError(f"{self.key} ({self.address}): {shown} is far out of range")
        if bare and not self.raw_min <= exact <= self.raw_max:
            self._hint_other_unit(number, shown)
        raw = round(exact)
        if abs(exact - raw) > 1e-6 * max(1.0, abs(exact)):
            step = f"{self.scale:g} {self.unit}".rstrip()
            raise ValidationError(f"{self.key}: {shown} is not a multiple of the resolution {step}")
        return raw

    def _hint_other_unit(self, number: float, shown: str) -> None:
        """A bare number out of range that fits when read as % (or as x): say so instead of "out of range"."""
        other = alternative_reading(number, self.unit)
        if other is not None and self.raw_min <= other[0] / self.scale <= self.raw_max:
            lo, hi = self.to_engineering(self.raw_min), self.to_engineering(self.raw_max)
            raise ValidationError(
                f"{self.key} ({self.address}): {shown} is out of range {lo}..{hi} {self.unit}; "
                f"did you mean {number:g}{other[1]} (= {other[0]:g} {self.unit})?"
            )

    def _parse_text(self, text: str) -> int:
        what = f"{self.key} ({self.address})"
        if self.enum is not None:
            raw = self.enum.lookup(text)
            if raw is not None:
                return raw
            code = text.strip()
            if re.fullmatch(r"[+-]?\d+|0[xX][0-9a-fA-F]+", code):
                return int(code, 0) if code.lower().startswith("0x") else int(code)
            raise ValidationError(
                f"{what}: {text!r} is not a choice; choose one of {self.enum.choices(self.raw_min, self.raw_max)}"
            )
        quantity = split_quantity(text)
        if quantity is None:
            unit = f" (a number, optionally with its unit {self.unit!r})" if self.unit else " (a number)"
            raise ValidationError(f"{what}: cannot read {text!r} as a value{unit}")
        number, unit = quantity
        if not math.isfinite(number):
            raise ValidationError(f"{what}: {text!r} is not a number")
        converted = convert_unit(number, unit, self.unit, what)
        return self._from_engineering(converted, text.strip(), bare=not unit)


def _finite(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) else None


@dataclass(frozen=True, slots=True)
class Value:
    """A value read from (or written to) a device, in engineering units, with how precise it is.

    ``resolution`` is the step of the path it came through: 0.1 A over Modbus, 1 A from a DeviceNet assembly.
    """

    point: PointDef
    raw: int
    value: float | int
    resolution: float
    source: str = ""

    @property
    def key(self) -> str:
        return self.point.key

    @property
    def unit(self) -> str:
        return self.point.unit

    @property
    def label(self) -> Label | None:
        return self.point.enum.label(self.raw) if self.point.enum is not None else None

    @classmethod
    def from_raw(cls, point: PointDef, raw: int, scale: float | None = None, source: str = "") -> Value:
        factor = point.scale if scale is None else scale
        if cls is not Value:
            return cls(point, raw, _engineering(raw, factor), factor, source)
        made = _ValueTwin()  # (a poll makes a Value per point read: no __init__, see frozen_twin.py)
        made.point, made.raw, made.resolution, made.source = point, raw, factor, source
        made.value = raw if factor == 1 else SCALED[factor][raw]
        made.__class__ = Value
        return made  # type: ignore[no-any-return]

    def text(self) -> str:
        """Human form: "390 A", "current limit (0)", "0x0900"."""
        if self.point.bits:
            return f"0x{self.raw:04X}"
        label = self.label
        if label is not None:
            return f"{label.en} ({self.raw})"
        if self.point.enum is not None:
            return f"unknown value {self.raw}"
        shown = f"{self.value:.{_decimals(self.resolution)}f}" if isinstance(self.value, float) else str(self.value)
        return f"{shown} {self.unit}".rstrip()

    def as_json(self) -> dict[str, object]:
        label = self.label
        return {
            "key": self.key,
            "address": self.point.address,
            "value": self.value,
            "raw": self.raw,
            "unit": self.unit,
            "resolution": self.resolution,
            "label": label.en if label else None,
            "source": self.source,
        }


_ValueTwin = twin(Value)


@dataclass(frozen=True, slots=True)
class Reading:
    """What a transport returns for one point: the raw word and the scale of the path it came through."""

    point: PointDef
    raw: int
    scale: float | None = None  # None: the profile's scale

    def value(self, source: str = "") -> Value:
        return Value.from_raw(self.point, self.raw, self.scale, source)


_ReadingTwin = twin(Reading)


def readings(points: Iterable[PointDef], raws: Iterable[int]) -> list[Reading]:
    """``Reading(point, raw)`` for each pair, on the profile's scale, built without ``__init__`` (a poll makes one
    a point: see frozen_twin.py). The two must be as long as each other."""
    out = []
    for point, raw in zip(points, raws, strict=True):
        made = _ReadingTwin()
        made.point, made.raw, made.scale = point, raw, None
        made.__class__ = Reading
        out.append(made)
    return out
