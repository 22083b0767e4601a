"""The protocol-neutral model: parameter/measurement definitions and the values read from them.

A :class:`PointDef` describes one 16-bit word of a device (a parameter or a measurement) with its raw range,
scale, unit, enum and its address on every protocol. Transports move raw integers; conversion to and from
engineering units happens here, once, for every transport.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from starterbus.core.errors import ValidationError


class Kind(str, enum.Enum):
    PARAMETER = "parameter"
    MEASUREMENT = "measurement"


class Access(str, enum.Enum):
    READ = "r"
    READ_WRITE = "rw"

    @property
    def writable(self) -> bool:
        return self is Access.READ_WRITE


@dataclass(frozen=True, slots=True)
class Label:
    """A text in English and in the manual's Chinese."""

    en: str
    zh: str = ""

    def __str__(self) -> str:
        return self.en


@dataclass(frozen=True, slots=True)
class EnumTable:
    """A format code of the manual (F1, F2, ...): raw value -> label."""

    name: str
    labels: Mapping[int, Label]

    def label(self, raw: int) -> Label | None:
        return self.labels.get(raw)

    def lookup(self, text: str) -> int | None:
        """Raw value for a label given in either language (case-insensitive), or None."""
        wanted = text.strip().casefold()
        for raw, label in self.labels.items():
            if wanted in (label.en.casefold(), label.zh.casefold()):
                return raw
        return None


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
    scale_assumed: bool = False
    addresses: Mapping[str, int] = field(default_factory=dict)  # protocol -> address (modbus, profibus, devicenet)
    note: str = ""

    @property
    def writable(self) -> bool:
        return self.kind is Kind.PARAMETER and self.access.writable

    def uncertainty(self, raw: int) -> str | None:
        """Why writing ``raw`` rests on an unprinted code or scale, or None when the manual prints both."""
        if self.scale_assumed:
            return f"{self.address} {self.key}: the scale {self.scale:g} is assumed, not printed in the manual"
        return None

    def address_for(self, protocol: str) -> int | None:
        return self.addresses.get(protocol)

    # -- conversion ---------------------------------------------------------------------------------------

    def to_engineering(self, raw: int, scale: float | None = None) -> float | int:
        """Raw word -> engineering value (``scale`` overrides the profile's, for transports with other resolution)."""
        factor = self.scale if scale is None else scale
        if factor == 1:
            return raw
        decimals = max(0, round(-math.log10(factor))) if 0 < factor < 1 else 0
        return round(raw * factor, decimals)

    def to_raw(self, value: float | int | str) -> int:
        """Engineering value or enum label -> raw word, validated against range and resolution.

        Raises :class:`ValidationError` naming the key and the value; nothing is rounded silently.
        """
        if isinstance(value, str):
            raw = self._parse_text(value)
        else:
            if isinstance(value, bool) or not math.isfinite(float(value)):
                raise ValidationError(f"{self.key}: {value!r} is not a number")
            exact = float(value) / self.scale
            raw = round(exact)
            if abs(exact - raw) > 1e-6 * max(1.0, abs(exact)):
                step = f"{self.scale:g} {self.unit}".rstrip()
                raise ValidationError(f"{self.key}: {value} {self.unit} is not a multiple of the resolution {step}")
        self.check_raw(raw)
        return raw

    def check_raw(self, raw: int) -> None:
        """Raise :class:`ValidationError` if a raw value is outside the range or the enum."""
        if not self.raw_min <= raw <= self.raw_max:
            lo, hi = self.to_engineering(self.raw_min), self.to_engineering(self.raw_max)
            shown = self.to_engineering(raw)
            raise ValidationError(
                f"{self.key} ({self.address}): {shown} {self.unit} is out of range {lo}..{hi} {self.unit}".replace(
                    "  ", " "
                ).rstrip()
            )
        if self.enum is not None and raw not in self.enum.labels:
            allowed = ", ".join(f"{k}={v.en}" for k, v in sorted(self.enum.labels.items()))
            raise ValidationError(f"{self.key} ({self.address}): {raw} is not one of {allowed}")

    def _parse_text(self, text: str) -> int:
        if self.enum is not None:
            raw = self.enum.lookup(text)
            if raw is not None:
                return raw
        cleaned = text.strip()
        if self.unit and cleaned.endswith(self.unit):
            cleaned = cleaned[: -len(self.unit)].strip()
        try:
            number = float(int(cleaned, 0)) if cleaned.lower().startswith("0x") else float(cleaned)
        except ValueError:
            choices = ""
            if self.enum is not None:
                choices = "; one of " + ", ".join(f"{v.en!r}" for v in self.enum.labels.values())
            raise ValidationError(f"{self.key}: cannot read {text!r} as a value{choices}") from None
        if self.enum is not None:
            if number != int(number):
                raise ValidationError(f"{self.key}: {text!r} is not an enum value")
            return int(number)
        exact = number / self.scale
        raw = round(exact)
        if abs(exact - raw) > 1e-6 * max(1.0, abs(exact)):
            raise ValidationError(f"{self.key}: {text} is not a multiple of the resolution {self.scale:g}")
        return raw


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
        return cls(point, raw, point.to_engineering(raw, factor), factor, source)

    def text(self) -> str:
        """Human form: "390 A", "current limit (0)", "0x0900"."""
        if self.point.bits:
            return f"0x{self.raw:04X}"
        label = self.label
        if label is not None:
            return f"{label.en} ({self.raw})"
        if self.point.enum is not None:
            return f"unknown value {self.raw}"
        if isinstance(self.value, float):
            digits = max(0, round(-math.log10(self.resolution))) if 0 < self.resolution < 1 else 0
            shown = f"{self.value:.{digits}f}"
        else:
            shown = str(self.value)
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


@dataclass(frozen=True, slots=True)
class Reading:
    """What a transport returns for one point: the raw word and the scale of the path it came through."""

    point: PointDef
    raw: int
    scale: float | None = None  # None: the profile's scale

    def value(self, source: str = "") -> Value:
        return Value.from_raw(self.point, self.raw, self.scale, source)
