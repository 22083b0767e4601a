"""The ``[transports]`` tables of a profile: one per address space, each parsed by the space's installed parser.

The core stays protocol-free: it finds the parser by the table's name (a space, or a transport that speaks one:
:mod:`starterbus.core.address_space`) and keeps what the parser returns.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

from starterbus.core.address_space import parser_of, space_of
from starterbus.core.errors import ProfileError, StarterbusError
from starterbus.core.model import PointDef
from starterbus.core.profile_points import AddressParser, int_key, key_text, label, shown, table


def parse_tables(data: Mapping[str, Any], source: str) -> tuple[dict[str, Mapping[str, Any]], dict[str, object]]:
    """The ``[transports.*]`` tables by address space (a table may name the space or a transport that speaks
    it), their ``exceptions`` / ``errors`` sub-tables parsed into code -> Label, and what each installed space
    parser made of them."""
    tables: dict[str, Mapping[str, Any]] = {}
    written: dict[str, str] = {}
    parsed: dict[str, object] = {}
    for tname, settings in data.items():
        where = f"transports.{key_text(tname)}"
        if not isinstance(settings, Mapping):
            raise ProfileError(source, where, f"must be a table of settings, not {shown(settings)}")
        space = space_of(str(tname))
        if space in written:
            raise ProfileError(
                source, where, f"names the {space} address space, as [transports.{key_text(written[space])}] does"
            )
        written[space] = str(tname)
        checked = dict(settings)
        for sub in ("exceptions", "errors"):
            if sub in checked:
                entries = table(checked, sub, source, f"{where}.")
                checked[sub] = {
                    int_key(k, source, f"{where}.{sub}"): label(v, source, f"{where}.{sub}.{key_text(k)}")[0]
                    for k, v in entries.items()
                }
        made = parse_settings(space, checked, source, where)
        if made is not None:
            parsed[space] = made
        tables[space] = MappingProxyType(checked)
    return tables, parsed


def parse_transports(
    data: Mapping[str, Any], points: Mapping[str, PointDef], source: str
) -> tuple[dict[str, Mapping[str, Any]], dict[str, object]]:
    """:func:`parse_tables`, then: a profile names at least one space, and a space whose parser requires point
    addresses has some."""
    tables, parsed = parse_tables(data, source)
    if not tables:
        raise ProfileError(source, "transports", "a profile must name at least one transport")
    for space in tables:
        parser = parser_of(space)
        if (
            parser is not None
            and parser.requires_point_addresses
            and not any(space in p.addresses for p in points.values())
        ):
            raise ProfileError(source, f"transports.{key_text(space)}", f"no point has a {space} address")
    return tables, parsed


def address_fields(data: Mapping[str, Any], source: str) -> dict[str, AddressParser]:
    """Each address space the profile names -> the parser of its point addresses (its parser's, when installed)."""
    names = data.get("transports")
    if not isinstance(names, Mapping):
        return {}  # reported, with the file and the key, when the transports table is read
    return {space_of(str(name)): parser_for(space_of(str(name))) for name in names}


def parser_for(space: str) -> AddressParser:
    """How the addresses of ``space`` are parsed: by its installed parser, else kept as written."""
    parser = parser_of(space)
    return parser.parse_address if parser is not None else _unchecked


def _unchecked(value: object) -> object:
    """The plugin is not installed: keep its address as written (lists as tuples, so it can be looked up)."""
    if isinstance(value, list):
        return tuple(_unchecked(v) for v in value)
    if isinstance(value, Mapping):
        return tuple(sorted((str(k), _unchecked(v)) for k, v in value.items()))
    return value


def parse_settings(space: str, settings: Mapping[str, Any], source: str, where: str) -> object | None:
    """Let the installed parser of ``space`` parse its settings (a parser not installed parses nothing)."""
    parser = parser_of(space)
    if parser is None:
        return None
    try:
        return parser.parse_settings(settings)
    except StarterbusError as exc:
        raise ProfileError(source, where, str(exc)) from None
