"""Device profiles: a model described as data (one TOML file per model), loaded and validated.

The schema is documented in ``docs/profiles.md``. Loading checks every rule a transport or simulator relies
on; any violation raises :class:`ProfileError` naming the file and the key.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from starterbus.core.errors import ProfileError, UnknownPointError
from starterbus.core.model import Access, EnumTable, Kind, Label, PointDef
from starterbus.core.status import FaultTable

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

SCHEMA_VERSION = 1
PROTOCOL_FIELDS = ("modbus", "profibus", "devicenet")
_KEY_RE = re.compile(r"^[a-z][a-z0-9_]*$")
_POINT_FIELDS = {
    "key",
    "address",
    "name_zh",
    "name_en",
    "min",
    "max",
    "scale",
    "unit",
    "enum",
    "default",
    "access",
    "format",
    "scale_assumed",
    "note",
    *PROTOCOL_FIELDS,
}
_ROLE_NAMES = {
    "control_word",
    "status_word",
    "phase_currents",
    "rated_current",
    "current_limit",
    "ramp_time",
    "stop_time",
    "max_start_current",
    "max_run_current",
    "start_count",
    "run_time",
    "last_fault_code",
    "last_fault_current",
}
_REQUIRED_ROLES = ("control_word", "status_word", "phase_currents", "rated_current", "current_limit")


@dataclass(frozen=True, slots=True)
class ControlTraits:
    bus_control_required: bool = False
    bit12_is_mains_voltage: bool = False
    write_protect_key: str = ""
    locked_while_running: frozenset[str] = frozenset()


@dataclass(frozen=True, slots=True)
class Profile:
    """One device model: its points, enums, faults, roles and per-transport facts."""

    name: str
    vendor: str
    display_name: str
    address_style: str  # "register" or "index"
    points: Mapping[str, PointDef]
    enums: Mapping[str, EnumTable]
    faults: FaultTable
    control: ControlTraits
    roles: Mapping[str, Any]  # role -> key (phase_currents -> list of keys)
    transports: Mapping[str, Mapping[str, Any]]  # transport name -> its settings table
    manuals: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    source: str = ""
    _by_address: Mapping[tuple[Kind | None, str], str] = field(default_factory=dict, repr=False)

    # -- lookup ---------------------------------------------------------------------------------------------

    @property
    def parameters(self) -> list[PointDef]:
        return [p for p in self.points.values() if p.kind is Kind.PARAMETER]

    @property
    def measurements(self) -> list[PointDef]:
        return [p for p in self.points.values() if p.kind is Kind.MEASUREMENT]

    def point(self, key_or_address: str) -> PointDef:
        """A point by snake_case key or by the manual's own address ("0x0103", "p7", "m3")."""
        text = key_or_address.strip()
        found = self.points.get(text) or self.points.get(text.lower())
        if found is not None:
            return found
        norm = _normalise_address(text, self.address_style)
        if norm is not None:
            key = self._by_address.get(norm) or self._by_address.get((None, norm[1]))
            if key is not None:
                return self.points[key]
        raise UnknownPointError(
            f"{self.name}: no parameter or measurement {key_or_address!r} "
            f"(use a key such as {next(iter(self.points))!r} or a manual address"
            f"{' like 0x0100' if self.address_style == 'register' else ' like p7 or m3'}; "
            f"`starterbus params {self.name}` lists them)"
        )

    def role(self, name: str) -> PointDef | None:
        key = self.roles.get(name)
        return self.points[key] if isinstance(key, str) else None

    def phase_currents(self) -> list[PointDef]:
        return [self.points[k] for k in self.roles.get("phase_currents", [])]

    def supports(self, transport: str) -> bool:
        return transport in self.transports

    def transport_settings(self, transport: str) -> Mapping[str, Any]:
        return self.transports.get(transport, {})

    def by_protocol_address(self, protocol: str, kind: Kind, address: int) -> PointDef | None:
        for point in self.points.values():
            if point.kind is kind and point.addresses.get(protocol) == address:
                return point
        return None


def _normalise_address(text: str, style: str) -> tuple[Kind | None, str] | None:
    t = text.strip().lower()
    if style == "index":
        m = re.fullmatch(r"([pm])\s*(0x[0-9a-f]+|\d+)", t)
        if m is None:
            return None
        kind = Kind.PARAMETER if m.group(1) == "p" else Kind.MEASUREMENT
        return kind, str(int(m.group(2), 0))
    m = re.fullmatch(r"(?:0x)?([0-9a-f]{1,4})h?", t)
    if m is None or not (t.startswith("0x") or t.endswith("h") or len(m.group(1)) == 4):
        return None
    return None, str(int(m.group(1), 16))


# -- loading ------------------------------------------------------------------------------------------------


def load_profile_file(path: str | Path) -> Profile:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ProfileError(str(path), "(file)", f"cannot read: {exc}") from exc
    return load_profile_text(text, str(path))


def load_profile_text(text: str, source: str = "<profile>") -> Profile:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(source, "(toml)", str(exc)) from exc
    return build_profile(data, source)


def build_profile(data: Mapping[str, Any], source: str) -> Profile:
    def fail(key: str, message: str) -> ProfileError:
        return ProfileError(source, key, message)

    if data.get("schema") != SCHEMA_VERSION:
        raise fail("schema", f"expected schema = {SCHEMA_VERSION}, got {data.get('schema')!r}")
    model = _table(data, "model", source)
    name = _str(model, "name", source, "model.")
    if not _KEY_RE.fullmatch(name):
        raise fail("model.name", f"{name!r} must be lowercase letters, digits and underscores")
    style = model.get("address_style", "register")
    if style not in ("register", "index"):
        raise fail("model.address_style", f"{style!r} is not 'register' or 'index'")

    enums: dict[str, EnumTable] = {}
    for enum_name, table in _table(data, "enums", source, required=False).items():
        if not isinstance(table, Mapping) or not table:
            raise fail(f"enums.{enum_name}", "must be a non-empty table of raw value -> {en, zh}")
        enums[enum_name] = EnumTable(
            enum_name,
            {
                _int_key(k, source, f"enums.{enum_name}"): _label(v, source, f"enums.{enum_name}.{k}")
                for k, v in table.items()
            },
        )

    faults = FaultTable(
        {
            _int_key(k, source, "faults"): _label(v, source, f"faults.{k}")
            for k, v in _table(data, "faults", source, required=False).items()
        }
    )
    for code in faults.labels:
        if not 0 <= code <= 63:
            raise fail(f"faults.{code}", "fault codes are 6 bits (0-63)")

    points: dict[str, PointDef] = {}
    used: dict[tuple[str, Kind, int], str] = {}
    by_address: dict[tuple[Kind | None, str], str] = {}
    for kind, section in ((Kind.MEASUREMENT, "measurements"), (Kind.PARAMETER, "parameters")):
        entries = data.get(section, [])
        if not isinstance(entries, list):
            raise fail(section, "must be an array of tables ([[...]])")
        for i, entry in enumerate(entries):
            where = f"{section}[{i}]"
            if not isinstance(entry, Mapping):
                raise fail(where, "must be a table")
            key = entry.get("key")
            if not isinstance(key, str) or not _KEY_RE.fullmatch(key):
                raise fail(f"{where}.key", f"{key!r} is not a snake_case key")
            where = f"{section}.{key}"
            unknown = set(entry) - _POINT_FIELDS
            if unknown:
                raise fail(where, f"unknown field(s) {sorted(unknown)}")
            if key in points:
                raise fail(where, "duplicate key")
            point = _build_point(entry, kind, key, enums, source, where)
            for proto, addr in point.addresses.items():
                slot = (proto, kind, addr)
                if slot in used:
                    raise fail(where, f"{proto} address {addr:#06x} overlaps {used[slot]}")
                used[slot] = key
            norm = _normalise_address(point.address, style)
            if norm is None:
                raise fail(f"{where}.address", f"{point.address!r} is not a {style}-style manual address")
            slot_key: tuple[Kind | None, str] = (kind, norm[1]) if style == "index" else (None, norm[1])
            if slot_key in by_address:
                raise fail(f"{where}.address", f"{point.address!r} is also the address of {by_address[slot_key]}")
            by_address[slot_key] = key
            points[key] = point

    control_table = _table(data, "control", source, required=False)
    control = ControlTraits(
        bus_control_required=bool(control_table.get("bus_control_required", False)),
        bit12_is_mains_voltage=control_table.get("status_bit12", "") == "mains_voltage",
        write_protect_key=str(control_table.get("write_protect_key", "")),
        locked_while_running=frozenset(control_table.get("locked_while_running", [])),
    )
    for ref in [control.write_protect_key, *control.locked_while_running]:
        if ref and (ref not in points or points[ref].kind is not Kind.PARAMETER):
            raise fail("control", f"{ref!r} is not a parameter of this profile")

    roles = dict(_table(data, "roles", source))
    for role, ref in roles.items():
        if role not in _ROLE_NAMES:
            raise fail(f"roles.{role}", f"unknown role (known: {sorted(_ROLE_NAMES)})")
        refs = ref if isinstance(ref, list) else [ref]
        for r in refs:
            if r not in points:
                raise fail(f"roles.{role}", f"{r!r} names no point of this profile")
    for role in _REQUIRED_ROLES:
        if role not in roles:
            raise fail(f"roles.{role}", "required role missing")

    transports = {str(k): dict(v) for k, v in _table(data, "transports", source).items()}
    if not transports:
        raise fail("transports", "a profile must name at least one transport")
    for proto, proto_key in (("modbus-rtu", "modbus"), ("profibus-pkw", "profibus")):
        if proto in transports and not any(proto_key in p.addresses for p in points.values()):
            raise fail(f"transports.{proto}", f"no point has a {proto_key} address")
    for tname, settings in transports.items():
        for table in ("exceptions", "errors"):
            if table in settings:
                settings[table] = {
                    _int_key(k, source, f"transports.{tname}.{table}"): _label(
                        v, source, f"transports.{tname}.{table}.{k}"
                    )
                    for k, v in settings[table].items()
                }

    return Profile(
        name=name,
        vendor=str(model.get("vendor", "")),
        display_name=str(model.get("display_name", name.upper())),
        address_style=style,
        points=points,
        enums=enums,
        faults=faults,
        control=control,
        roles=roles,
        transports=transports,
        manuals=tuple(model.get("manuals", ())),
        notes=tuple(model.get("notes", ())),
        source=source,
        _by_address=by_address,
    )


def _build_point(
    entry: Mapping[str, Any], kind: Kind, key: str, enums: Mapping[str, EnumTable], source: str, where: str
) -> PointDef:
    def fail(field_name: str, message: str) -> ProfileError:
        return ProfileError(source, f"{where}.{field_name}" if field_name else where, message)

    raw_min, raw_max = entry.get("min"), entry.get("max")
    if not isinstance(raw_min, int) or not isinstance(raw_max, int):
        raise fail("min", "min and max must be integers (raw values)")
    if raw_min > raw_max:
        raise fail("min", f"inverted range {raw_min} > {raw_max}")
    if raw_min < -0x8000 or raw_max > 0xFFFF:
        raise fail("max", f"range {raw_min}..{raw_max} does not fit a 16-bit word")
    scale = entry.get("scale", 1)
    if not isinstance(scale, (int, float)) or scale <= 0:
        raise fail("scale", f"{scale!r} must be a positive number")
    enum_table = None
    if "enum" in entry:
        enum_table = enums.get(entry["enum"])
        if enum_table is None:
            raise fail("enum", f"unknown enum {entry['enum']!r} (defined: {sorted(enums)})")
        if not any(raw_min <= v <= raw_max for v in enum_table.labels):
            raise fail("enum", f"no value of {entry['enum']} lies in {raw_min}..{raw_max}")
    access_text = entry.get("access", "rw" if kind is Kind.PARAMETER else "r")
    try:
        access = Access(access_text)
    except ValueError:
        raise fail("access", f"{access_text!r} is not 'r' or 'rw'") from None
    if kind is Kind.MEASUREMENT and access is not Access.READ:
        raise fail("access", "measurements are read-only")
    default = entry.get("default")
    if default is not None and (not isinstance(default, int) or not raw_min <= default <= raw_max):
        raise fail("default", f"{default!r} is outside {raw_min}..{raw_max}")
    addresses: dict[str, int] = {}
    for proto in PROTOCOL_FIELDS:
        if proto in entry:
            addr = entry[proto]
            if not isinstance(addr, int) or not 0 <= addr <= 0xFFFF:
                raise fail(proto, f"{addr!r} is not an address")
            addresses[proto] = addr
    for text_field in ("address", "name_en"):
        if not isinstance(entry.get(text_field), str) or not entry[text_field]:
            raise fail(text_field, "required text")
    return PointDef(
        key=key,
        kind=kind,
        address=entry["address"],
        name_zh=str(entry.get("name_zh", "")),
        name_en=entry["name_en"],
        raw_min=raw_min,
        raw_max=raw_max,
        scale=float(scale),
        unit=str(entry.get("unit", "")),
        enum=enum_table,
        access=access,
        default=default,
        bits=entry.get("format") == "bits",
        scale_assumed=bool(entry.get("scale_assumed", False)),
        addresses=addresses,
        note=str(entry.get("note", "")),
    )


def _table(data: Mapping[str, Any], name: str, source: str, required: bool = True) -> Mapping[str, Any]:
    value = data.get(name)
    if value is None:
        if required:
            raise ProfileError(source, name, "required table missing")
        return {}
    if not isinstance(value, Mapping):
        raise ProfileError(source, name, "must be a table")
    return value


def _str(table: Mapping[str, Any], key: str, source: str, prefix: str) -> str:
    value = table.get(key)
    if not isinstance(value, str) or not value:
        raise ProfileError(source, prefix + key, "required text")
    return value


def _int_key(key: object, source: str, where: str) -> int:
    try:
        return int(str(key), 0)
    except ValueError:
        raise ProfileError(source, f"{where}.{key}", "keys must be integers") from None


def _label(value: object, source: str, where: str) -> Label:
    if isinstance(value, str):
        return Label(value)
    if isinstance(value, Mapping) and isinstance(value.get("en"), str):
        return Label(value["en"], str(value.get("zh", "")))
    raise ProfileError(source, where, "must be a text or a table {en = ..., zh = ...}")
