"""The ``[transports]`` tables of a profile: each installed plugin parses its own table and its address field.

The core stays protocol-free: it finds the plugin by the table's name and keeps what the plugin returns.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from starterbus.core.errors import ProfileError, StarterbusError
from starterbus.core.model import PointDef
from starterbus.core.profile_points import AddressParser, int_key, key_text, label, shown, table

if TYPE_CHECKING:
    from starterbus.core.plugin import TransportPlugin


def parse_transports(
    data: Mapping[str, Any], points: Mapping[str, PointDef], source: str
) -> tuple[dict[str, Mapping[str, Any]], dict[str, object]]:
    """The tables as written, and what each installed plugin parsed them into."""
    transports: dict[str, Mapping[str, Any]] = {}
    parsed: dict[str, object] = {}
    for tname, settings in data.items():
        where = f"transports.{key_text(tname)}"
        if not isinstance(settings, Mapping):
            raise ProfileError(source, where, f"must be a table of settings, not {shown(settings)}")
        checked = dict(settings)
        for sub in ("exceptions", "errors"):
            if sub in checked:
                entries = table(checked, sub, source, f"{where}.")
                checked[sub] = {
                    int_key(k, source, f"{where}.{sub}"): label(v, source, f"{where}.{sub}.{key_text(k)}")[0]
                    for k, v in entries.items()
                }
        made = parse_settings(str(tname), checked, source, where)
        if made is not None:
            parsed[str(tname)] = made
        transports[str(tname)] = checked
    if not transports:
        raise ProfileError(source, "transports", "a profile must name at least one transport")
    for name in transports:
        plugin = plugin_named(name)
        if (
            plugin is not None
            and plugin.requires_point_addresses
            and not any(name in p.addresses for p in points.values())
        ):
            raise ProfileError(source, f"transports.{key_text(name)}", f"no point has a {name} address")
    return transports, parsed


def plugin_named(name: str) -> TransportPlugin | None:
    """The installed plugin of that name, or None (a profile may name a transport that is not installed)."""
    from starterbus.core.registry import transports  # late: the registry imports this module

    try:
        return transports.get(name)
    except StarterbusError:
        return None


def address_fields(data: Mapping[str, Any], source: str) -> dict[str, AddressParser]:
    """Each transport the profile names -> the parser of its point addresses (the plugin's, when installed)."""
    names = data.get("transports")
    if not isinstance(names, Mapping):
        return {}  # reported, with the file and the key, when the transports table is read
    fields: dict[str, AddressParser] = {}
    for name in names:
        plugin = plugin_named(str(name))
        fields[str(name)] = plugin.parse_address if plugin is not None else _unchecked
    return fields


def _unchecked(value: object) -> object:
    """The plugin is not installed: keep its address as written (lists as tuples, so it can be looked up)."""
    if isinstance(value, list):
        return tuple(_unchecked(v) for v in value)
    if isinstance(value, Mapping):
        return tuple(sorted((str(k), _unchecked(v)) for k, v in value.items()))
    return value


def parse_settings(name: str, settings: Mapping[str, Any], source: str, where: str) -> object | None:
    """Let the installed plugin of that name parse its settings (a plugin not installed parses nothing)."""
    plugin = plugin_named(name)
    if plugin is None:
        return None
    try:
        return plugin.parse_settings(settings)
    except StarterbusError as exc:
        raise ProfileError(source, where, str(exc)) from None
