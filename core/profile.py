"""Device profiles: a model described as data (one TOML file per model), loaded and validated.

The schema is documented in ``docs/profiles.md``. Loading checks every rule a transport or simulator relies
on; any violation raises :class:`ProfileError` naming the file and the key. What loading gives, the
:class:`Profile` and its lookups, lives in :mod:`starterbus.core.profile_model` (its names importable from here).
"""

from __future__ import annotations

import re
import sys
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from starterbus.core.address_space import space_of
from starterbus.core.errors import ProfileError
from starterbus.core.model import Certainty, EnumTable, Kind, PointDef, Provenance
from starterbus.core.profile_model import ControlTraits, Profile, normalise_address
from starterbus.core.profile_points import (
    POINT_FIELDS,
    AddressParser,
    build_point,
    enum_table,
    is_int,
    key_text,
    provenance,
    shown,
    table,
    text,
    text_list,
)
from starterbus.core.profile_transports import address_fields, parse_transports
from starterbus.core.status import FaultTable
from starterbus.core.textinput import read_text_file

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

SCHEMA_VERSION = 1
_KEY_RE = re.compile(r"^[a-z][a-z0-9_]*$")
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


# -- loading ------------------------------------------------------------------------------------------------


def load_profile_file(path: str | Path) -> Profile:
    text = read_text_file(path, "profile", error=lambda source, detail: ProfileError(source, "(file)", detail))
    return load_profile_text(text, str(path))


def load_profile_text(text: str, source: str = "<profile>") -> Profile:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(source, "(toml)", str(exc)) from exc
    return build_profile(data, source)


def build_profile(data: Mapping[str, Any], source: str) -> Profile:
    """A profile from parsed TOML data; any problem raises :class:`ProfileError` naming file, key and value."""

    def fail(key: str, message: str) -> ProfileError:
        return ProfileError(source, key, message)

    if not isinstance(data, Mapping):
        raise fail("(document)", "must be a table")
    if data.get("schema") != SCHEMA_VERSION or isinstance(data.get("schema"), bool):
        raise fail("schema", f"expected schema = {SCHEMA_VERSION}, got {shown(data.get('schema'))}")
    model = table(data, "model", source)
    name = text(model, "name", source, "model.")
    if not _KEY_RE.fullmatch(name):
        raise fail("model.name", f"{name!r} must be lowercase letters, digits and underscores")
    style = model.get("address_style", "register")
    if style not in ("register", "index"):
        raise fail("model.address_style", f"{shown(style)} is not 'register' or 'index'")
    codes = _model_certainty(model, "certainty", source)
    defaults = _model_certainty(model, "default_certainty", source)

    enums = {
        str(n): enum_table(str(n), t, source, codes) for n, t in table(data, "enums", source, required=False).items()
    }
    fault_table = enum_table("faults", table(data, "faults", source, required=False), source, codes, "faults", 0, 63)
    faults = FaultTable(fault_table.labels)
    points, by_address = _points(data, style, enums, source, (codes, defaults), address_fields(data, source))
    control = _control(table(data, "control", source, required=False), points, source)
    roles = _roles(table(data, "roles", source), points, source)
    transports, settings = parse_transports(table(data, "transports", source), points, source)

    return Profile(
        name=name,
        vendor=text(model, "vendor", source, "model.", ""),
        display_name=text(model, "display_name", source, "model.", name.upper()),
        address_style=style,
        points=points,
        enums=enums,
        faults=faults,
        fault_sources=fault_table.sources,
        control=control,
        roles=roles,
        spaces=transports,
        manuals=text_list(model, "manuals", source, "model."),
        notes=text_list(model, "notes", source, "model."),
        source=source,
        _by_address=by_address,
        _settings=settings,
    )


def _model_certainty(model: Mapping[str, Any], key: str, source: str) -> Provenance:
    """The profile-wide default; absent means "assumed" (printed only where the author verified the manual)."""
    if key not in model:
        return Provenance(Certainty.ASSUMED)
    return provenance(model[key], source, f"model.{key}", need_why=False)


def _points(
    data: Mapping[str, Any],
    style: str,
    enums: Mapping[str, EnumTable],
    source: str,
    defaults: tuple[Provenance, Provenance],
    address_fields: Mapping[str, AddressParser],
) -> tuple[dict[str, PointDef], dict[tuple[Kind | None, str], str]]:
    tables = data.get("transports")
    written = [str(name) for name in tables] if isinstance(tables, Mapping) else []
    points: dict[str, PointDef] = {}
    used: dict[tuple[str, Kind, object], str] = {}
    by_address: dict[tuple[Kind | None, str], str] = {}
    for kind, section in ((Kind.MEASUREMENT, "measurements"), (Kind.PARAMETER, "parameters")):
        entries = data.get(section, [])
        if not isinstance(entries, list):
            raise ProfileError(source, section, f"must be an array of tables ([[...]]), not {shown(entries)}")
        for i, entry in enumerate(entries):
            where = f"{section}[{i}]"
            if not isinstance(entry, Mapping):
                raise ProfileError(source, where, f"must be a table, not {shown(entry)}")
            key = entry.get("key")
            if not isinstance(key, str) or not _KEY_RE.fullmatch(key):
                raise ProfileError(source, f"{where}.key", f"{shown(key)} is not a snake_case key")
            where = f"{section}.{key}"
            fields = _address_fields(entry, source, where)
            unknown = {name for name, space in fields.items() if space not in address_fields}
            if unknown:
                raise ProfileError(
                    source,
                    where,
                    f"unknown field(s) {sorted(unknown)} (addresses go in a field named after an address space "
                    f"of [transports], or a transport that speaks it: {', '.join(written) or 'none named'})",
                )
            if key in points:
                raise ProfileError(source, where, "duplicate key")
            parsers = {name: address_fields[space] for name, space in fields.items()}
            point = build_point(entry, kind, key, enums, source, where, defaults, parsers)  # addresses by space
            for proto, addr in point.addresses.items():
                slot = (proto, kind, addr)
                try:
                    hash(slot)
                except TypeError:
                    raise ProfileError(
                        source, f"{where}.{key_text(proto)}", f"{shown(addr)} is not a usable address (unhashable)"
                    ) from None
                if slot in used:
                    shown_addr = f"{addr:#06x}" if isinstance(addr, int) else repr(addr)
                    raise ProfileError(source, where, f"{proto} address {shown_addr} overlaps {used[slot]}")
                used[slot] = key
            norm = normalise_address(point.address, style)
            if norm is None or norm[0] not in (None, kind):
                raise ProfileError(
                    source,
                    f"{where}.address",
                    f"{point.address!r} is not a {style}-style manual address of a {kind.value}",
                )
            slot_key: tuple[Kind | None, str] = (kind, norm[1]) if style == "index" else (None, norm[1])
            if slot_key in by_address:
                raise ProfileError(
                    source, f"{where}.address", f"{point.address!r} is also the address of {by_address[slot_key]}"
                )
            by_address[slot_key] = key
            points[key] = point
    return points, by_address


def _address_fields(entry: Mapping[str, Any], source: str, where: str) -> dict[str, str]:
    """The point's address fields as written -> their address spaces (``modbus-rtu = ...`` gives the ``modbus``
    address its plugin speaks); two fields giving one space is an error."""
    fields: dict[str, str] = {}
    seen: dict[str, str] = {}
    for name in entry:
        if name in POINT_FIELDS:
            continue
        space = space_of(str(name))
        if space in seen:
            raise ProfileError(source, where, f"{seen[space]!r} and {name!r} both give the {space} address")
        fields[str(name)] = space
        seen[space] = str(name)
    return fields


def _control(data: Mapping[str, Any], points: Mapping[str, PointDef], source: str) -> ControlTraits:
    def flag(key: str) -> bool:
        value = data.get(key, False)
        if not isinstance(value, bool):
            raise ProfileError(source, f"control.{key}", f"{shown(value)} is not true or false")
        return value

    bit12 = text(data, "status_bit12", source, "control.", "")
    if bit12 not in ("", "mains_voltage"):
        raise ProfileError(source, "control.status_bit12", f"{bit12!r} is not '' or 'mains_voltage'")
    control = ControlTraits(
        bus_control_required=flag("bus_control_required"),
        bit12_is_mains_voltage=bit12 == "mains_voltage",
        write_protect_key=text(data, "write_protect_key", source, "control.", ""),
        locked_while_running=frozenset(text_list(data, "locked_while_running", source, "control.")),
        source_key=text(data, "source_key", source, "control.", ""),
    )
    for ref in [control.write_protect_key, control.source_key, *sorted(control.locked_while_running)]:
        if ref and (ref not in points or points[ref].kind is not Kind.PARAMETER):
            raise ProfileError(source, "control", f"{ref!r} is not a parameter of this profile")
    return _control_source(control, data.get("source_bus_codes"), points, source)


def _control_source(
    control: ControlTraits, codes: object, points: Mapping[str, PointDef], source: str
) -> ControlTraits:
    """``source_key`` and ``source_bus_codes`` come together: the codes are values of the key's enum."""
    where = "control.source_bus_codes"
    if not control.source_key:
        if codes is not None:
            raise ProfileError(source, where, "given without control.source_key")
        return control
    if not isinstance(codes, list) or not codes or not all(is_int(c) for c in codes):
        raise ProfileError(source, where, f"{shown(codes)} is not a non-empty list of codes that let the bus command")
    point = points[control.source_key]
    for code in codes:
        if point.enum is None or code not in point.enum.labels:
            raise ProfileError(source, where, f"{code} is not a code of {control.source_key}")
    return replace(control, source_bus_codes=tuple(codes))


def _roles(data: Mapping[str, Any], points: Mapping[str, PointDef], source: str) -> dict[str, Any]:
    roles: dict[str, Any] = {}
    for role, ref in data.items():
        where = f"roles.{key_text(role)}"
        if role not in _ROLE_NAMES:
            raise ProfileError(source, where, f"unknown role (known: {sorted(_ROLE_NAMES)})")
        if role == "phase_currents":
            if not isinstance(ref, list) or not ref or not all(isinstance(r, str) for r in ref):
                raise ProfileError(source, where, f"{shown(ref)} is not a non-empty list of point keys")
            refs = list(ref)
        elif isinstance(ref, str):
            refs = [ref]
        else:
            raise ProfileError(source, where, f"{shown(ref)} is not a point key")
        for r in refs:
            if r not in points:
                raise ProfileError(source, where, f"{r!r} names no point of this profile")
        roles[role] = ref
    for role in _REQUIRED_ROLES:
        if role not in roles:
            raise ProfileError(source, f"roles.{role}", "required role missing")
    return roles


__all__ = [
    "SCHEMA_VERSION",
    "ControlTraits",
    "Profile",
    "build_profile",
    "load_profile_file",
    "load_profile_text",
    "normalise_address",
]
