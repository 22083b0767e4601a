"""Reading the parts of a profile file: typed fields, labels, certainty, enum tables and points.

Every reader raises :class:`ProfileError` naming the file, the key and the offending value; no input makes
them raise anything else. ``docs/profiles.md`` documents the schema.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from typing import Any

from starterbus.core.errors import ProfileError, StarterbusError
from starterbus.core.model import Access, Certainty, EnumTable, Kind, Label, PointDef, Provenance

#: a point's address on a transport sits in a field named after the transport plugin (``NAME = ...``), parsed
#: by that plugin's ``parse_address``; the fields below are the model's own
POINT_FIELDS = {
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
    "note",
    "scale_certainty",
    "default_certainty",
    "address_certainty",
    "writable_values",
    "writable_why",
}
AddressParser = Callable[[object], Any]
_LABEL_FIELDS = {"en", "zh", "aliases", "certainty"}
_WORD = (-0x8000, 0xFFFF)


def shown(value: object) -> str:
    """A value for an error message, cut short."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def key_text(key: object) -> str:
    """A key of the file as it goes into a dotted path: as is if plain, else quoted (keeps messages on one line)."""
    text = str(key)
    return text if re.fullmatch(r"[\w+-]+", text) else repr(text)


def is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def as_int(value: object) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def table(data: Mapping[str, Any], name: str, source: str, where: str = "", required: bool = True) -> Mapping[str, Any]:
    value = data.get(name)
    path = f"{where}{name}"
    if value is None:
        if required:
            raise ProfileError(source, path, "required table missing")
        return {}
    if not isinstance(value, Mapping):
        raise ProfileError(source, path, f"must be a table, not {shown(value)}")
    return value


def text(data: Mapping[str, Any], name: str, source: str, where: str, default: str | None = None) -> str:
    value = data.get(name, default)
    if not isinstance(value, str) or (default is None and not value):
        raise ProfileError(
            source, f"{where}{name}", f"{shown(value)} is not a text" if value is not None else "required text"
        )
    return value


def text_list(data: Mapping[str, Any], name: str, source: str, where: str) -> tuple[str, ...]:
    value = data.get(name, [])
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ProfileError(source, f"{where}{name}", f"{shown(value)} is not a list of texts")
    return tuple(value)


def int_key(key: object, source: str, where: str, lo: int = _WORD[0], hi: int = _WORD[1]) -> int:
    text_key = str(key).strip()
    try:
        value = int(text_key, 16) if text_key.lower().startswith("0x") else int(text_key, 10)
    except ValueError:
        raise ProfileError(source, f"{where}.{key_text(key)}", f"the key {shown(key)} is not an integer") from None
    if not lo <= value <= hi:
        raise ProfileError(source, f"{where}.{key_text(key)}", f"{value} is outside {lo}..{hi}")
    return value


def provenance(value: object, source: str, where: str, need_why: bool = True) -> Provenance:
    """``"printed"``, ``"inferred from the print order"``, ``"assumed (no coding printed)"``: word, then why."""
    if not isinstance(value, str):
        raise ProfileError(source, where, f"{shown(value)} is not a text starting with printed, inferred or assumed")
    word, _, why = value.strip().partition(" ")
    try:
        certainty = Certainty(word)
    except ValueError:
        raise ProfileError(source, where, f"{shown(value)} does not start with printed, inferred or assumed") from None
    if need_why and certainty is not Certainty.PRINTED and not why.strip():
        raise ProfileError(source, where, f"{shown(value)}: say why, e.g. '{word} from the print order'")
    return Provenance(certainty, why.strip())


def label(value: object, source: str, where: str) -> tuple[Label, Provenance | None]:
    """A label and its own certainty, if it states one."""
    if isinstance(value, str):
        return Label(value), None
    if not isinstance(value, Mapping) or not isinstance(value.get("en"), str):
        raise ProfileError(source, where, f"{shown(value)} is not a text or a table {{en = ..., zh = ...}}")
    unknown = sorted(set(value) - _LABEL_FIELDS)
    if unknown:
        raise ProfileError(source, where, f"unknown field(s) {unknown} (known: {sorted(_LABEL_FIELDS)})")
    zh = value.get("zh", "")
    if not isinstance(zh, str):
        raise ProfileError(source, f"{where}.zh", f"{shown(zh)} is not a text")
    aliases = text_list(value, "aliases", source, f"{where}.")
    own = provenance(value["certainty"], source, f"{where}.certainty") if "certainty" in value else None
    return Label(value["en"], zh, aliases), own


def enum_table(
    name: str, data: object, source: str, default: Provenance, where: str = "", lo: int = _WORD[0], hi: int = _WORD[1]
) -> EnumTable:
    """An ``[enums.NAME]`` table (or ``[faults]``): codes -> labels, a ``certainty`` for all, per-code overrides."""
    where = where or f"enums.{key_text(name)}"
    if not isinstance(data, Mapping) or (not data and where != "faults"):
        raise ProfileError(source, where, "must be a non-empty table of raw value -> {en, zh}")
    base = provenance(data["certainty"], source, f"{where}.certainty") if "certainty" in data else default
    labels: dict[int, Label] = {}
    sources: dict[int, Provenance] = {}
    for key, value in data.items():
        if key == "certainty":
            continue
        code = int_key(key, source, where, lo, hi)
        if code in labels:
            raise ProfileError(source, f"{where}.{key_text(key)}", f"code {code} is given twice")
        labels[code], own = label(value, source, f"{where}.{key_text(key)}")
        sources[code] = own or base
    if not labels and not where.startswith("faults"):
        raise ProfileError(source, where, "has no codes")
    return EnumTable(name, labels, sources)


def build_point(
    entry: Mapping[str, Any],
    kind: Kind,
    key: str,
    enums: Mapping[str, EnumTable],
    source: str,
    where: str,
    defaults: tuple[Provenance, Provenance],
    address_fields: Mapping[str, AddressParser] | None = None,
) -> PointDef:
    """One ``[[parameters]]`` / ``[[measurements]]`` entry.

    ``defaults``: the model's certainty of codes and scales, and of defaults. ``address_fields``: transport name
    -> the parser of that transport's addresses (its plugin's ``parse_address``).
    """

    def fail(field_name: str, message: str) -> ProfileError:
        return ProfileError(source, f"{where}.{field_name}" if field_name else where, message)

    raw_min, raw_max = as_int(entry.get("min")), as_int(entry.get("max"))
    if raw_min is None or raw_max is None:
        raise fail(
            "min",
            f"min and max must be integers (raw values), not {shown(entry.get('min'))} and {shown(entry.get('max'))}",
        )
    if raw_min > raw_max:
        raise fail("min", f"inverted range {raw_min} > {raw_max}")
    if raw_min < _WORD[0] or raw_max > _WORD[1]:
        raise fail("max", f"range {raw_min}..{raw_max} does not fit a 16-bit word")
    scale = entry.get("scale", 1)
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale <= 0:
        raise fail("scale", f"{shown(scale)} must be a positive number")
    enum = None
    if "enum" in entry:
        enum_name = entry["enum"]
        if not isinstance(enum_name, str) or enum_name not in enums:
            raise fail("enum", f"unknown enum {shown(enum_name)} (defined: {sorted(enums)})")
        enum = enums[enum_name]
        if not any(raw_min <= v <= raw_max for v in enum.labels):
            raise fail("enum", f"no value of {enum_name} lies in {raw_min}..{raw_max}")
    access_text = entry.get("access", "rw" if kind is Kind.PARAMETER else "r")
    if access_text not in ("r", "rw"):
        raise fail("access", f"{shown(access_text)} is not 'r' or 'rw'")
    access = Access(access_text)
    if kind is Kind.MEASUREMENT and access is not Access.READ:
        raise fail("access", "measurements are read-only")
    default = entry.get("default")
    if default is not None and (not is_int(default) or not raw_min <= default <= raw_max):
        raise fail("default", f"{shown(default)} is outside {raw_min}..{raw_max}")
    fmt = entry.get("format")
    if fmt is not None and fmt != "bits":
        raise fail("format", f"{shown(fmt)} is not 'bits'")
    addresses: dict[str, Any] = {}
    for transport, parse in (address_fields or {}).items():
        if transport in entry:
            try:
                addresses[transport] = parse(entry[transport])
            except StarterbusError as exc:
                raise fail(key_text(transport), str(exc)) from None
    for field_name in ("address", "name_en"):
        if not isinstance(entry.get(field_name), str) or not entry[field_name]:
            raise fail(field_name, f"required text, not {shown(entry.get(field_name))}")
    for field_name in ("name_zh", "unit", "note", "writable_why"):
        if not isinstance(entry.get(field_name, ""), str):
            raise fail(field_name, f"{shown(entry[field_name])} is not a text")
    writable_values = None
    if "writable_values" in entry:
        values = entry["writable_values"]
        if not isinstance(values, list) or not values or not all(is_int(v) for v in values):
            raise fail("writable_values", f"{shown(values)} is not a non-empty list of raw values")
        for v in values:
            if not raw_min <= v <= raw_max or (enum is not None and v not in enum.labels):
                raise fail("writable_values", f"{v} is not a valid value of this point")
        if access is not Access.READ_WRITE:
            raise fail("writable_values", "the point is read-only")
        writable_values = frozenset(values)
    codes, default_source = defaults

    def certainty(field_name: str, fallback: Provenance) -> Provenance:
        if field_name not in entry:
            return fallback
        return provenance(entry[field_name], source, f"{where}.{field_name}")

    return PointDef(
        key=key,
        kind=kind,
        address=entry["address"],
        name_zh=entry.get("name_zh", ""),
        name_en=entry["name_en"],
        raw_min=raw_min,
        raw_max=raw_max,
        scale=float(scale),
        unit=entry.get("unit", ""),
        enum=enum,
        access=access,
        default=default,
        bits=fmt == "bits",
        addresses=addresses,
        note=entry.get("note", ""),
        scale_source=certainty("scale_certainty", codes),
        default_source=certainty("default_certainty", default_source),
        address_source=certainty("address_certainty", Provenance()),
        writable_values=writable_values,
        writable_why=entry.get("writable_why", ""),
    )
