"""Overlays: a plugin adds an address space to a shipped model without renaming it or copying its file.

An overlay is a small TOML document (or its parsed mapping) registered in the ``starterbus.overlays`` entry-point
group under ``MODEL.NAME`` (``jjr5000.acme``)::

    schema = 1
    [overlay]
    model = "jjr5000"

    [transports.acme-space]          # a table the model does not have yet (never replaces one)
    nodes = [1, 127]

    [addresses.acme-space]           # point key -> its address in that space
    phase_a_current = "R12"

The space's parser (``starterbus.address_spaces`` entry, or the plugin of that name) checks the table and every
address exactly as if the model's own file held them; the model keeps its name.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

from starterbus.core.address_space import parser_of, space_of
from starterbus.core.errors import ProfileError
from starterbus.core.model import PointDef
from starterbus.core.profile import Profile
from starterbus.core.profile_points import key_text, shown, table
from starterbus.core.profile_transports import parse_tables, parser_for


def apply_overlay(profile: Profile, data: Mapping[str, Any], source: str) -> Profile:
    """``profile`` with the overlay's tables and addresses added; ProfileError naming the overlay on any problem."""

    def fail(key: str, message: str) -> ProfileError:
        return ProfileError(source, key, message)

    if not isinstance(data, Mapping):
        raise fail("(document)", "must be a table")
    if data.get("schema") != 1 or isinstance(data.get("schema"), bool):
        raise fail("schema", f"expected schema = 1, got {shown(data.get('schema'))}")
    unknown = sorted(set(data) - {"schema", "overlay", "transports", "addresses"})
    if unknown:
        raise fail("(document)", f"unknown table(s) {unknown} (known: overlay, transports, addresses)")
    head = table(data, "overlay", source)
    if head.get("model") != profile.name:
        raise fail("overlay.model", f"{shown(head.get('model'))} is not {profile.name!r}, the model it extends")
    spaces, settings = parse_tables(table(data, "transports", source), source)
    for space in spaces:
        if space in profile.spaces:
            raise fail(
                f"transports.{key_text(space)}",
                f"{profile.name} already has the {space} address space (an overlay adds)",
            )
    added: dict[str, dict[str, Any]] = {}
    for name, entries in table(data, "addresses", source, required=False).items():
        space = space_of(str(name))
        where = f"addresses.{key_text(name)}"
        if space not in spaces:
            raise fail(where, f"names no address space of this overlay's [transports] ({', '.join(spaces) or 'none'})")
        if not isinstance(entries, Mapping):
            raise fail(where, f"must be a table of point key -> address, not {shown(entries)}")
        parse = parser_for(space)
        for key, value in entries.items():
            if key not in profile.points:
                raise fail(f"{where}.{key_text(key)}", f"{profile.name} has no point {key!r}")
            try:
                address = parse(value)
            except Exception as exc:
                raise fail(f"{where}.{key_text(key)}", str(exc)) from None
            added.setdefault(str(key), {})[space] = address
    _check_unique(profile, added, source)
    points: dict[str, PointDef] = {}
    for key, point in profile.points.items():
        extra = added.get(key)
        points[key] = replace(point, addresses={**point.addresses, **extra}) if extra else point
    _check_required(spaces, points, source)
    return replace(
        profile,
        points=points,
        spaces={**profile.spaces, **spaces},
        overlays=(*profile.overlays, source),
        _settings={**profile._settings, **settings},
    )


def _check_unique(profile: Profile, added: Mapping[str, Mapping[str, Any]], source: str) -> None:
    used: dict[tuple[str, object, object], str] = {}
    for key, addresses in added.items():
        kind = profile.points[key].kind
        for space, address in addresses.items():
            try:
                slot = (space, kind, address)
                other = used.setdefault(slot, key)
            except TypeError:
                raise ProfileError(source, f"addresses.{space}.{key}", f"{shown(address)} is unhashable") from None
            if other != key:
                raise ProfileError(source, f"addresses.{space}.{key}", f"{shown(address)} is also {other}'s address")


def _check_required(spaces: Mapping[str, object], points: Mapping[str, PointDef], source: str) -> None:
    for space in spaces:
        parser = parser_of(space)
        required = parser is not None and parser.requires_point_addresses
        if required and not any(space in p.addresses for p in points.values()):
            raise ProfileError(source, f"addresses.{key_text(space)}", f"no point has a {space} address")
