"""Checks a transport plugin runs on its ``[transports.NAME]`` table of a profile (``parse_settings``), and
:func:`build`, which makes the plugin's frozen settings object of the checked table.

Each raises :class:`ConfigurationError` naming the key and the value; the profile loader adds the file.
Absent keys are fine: the settings object's field holds the one default.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterable, Mapping
from types import MappingProxyType
from typing import Any, TypeVar

from starterbus.core.errors import ConfigurationError

T = TypeVar("T")


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _shown(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def known_keys(settings: Mapping[str, Any], known: Iterable[str]) -> None:
    allowed = set(known)
    for key in sorted(set(settings) - allowed):
        shown = key if re.fullmatch(r"[\w.+-]+", key) else repr(key)
        raise ConfigurationError(f"{shown}: unknown setting (known: {', '.join(sorted(allowed))})")


def int_value(settings: Mapping[str, Any], key: str, lo: int, hi: int) -> None:
    if key in settings:
        value = settings[key]
        if not _is_int(value) or not lo <= value <= hi:
            raise ConfigurationError(f"{key}: {_shown(value)} is not an integer in {lo}..{hi}")


def int_range(settings: Mapping[str, Any], key: str, lo: int, hi: int) -> None:
    """``key = [first, last]``: two integers, first <= last, both within lo..hi."""
    if key in settings:
        value = settings[key]
        if (
            not isinstance(value, list)
            or len(value) != 2
            or not all(_is_int(v) for v in value)
            or not lo <= value[0] <= value[1] <= hi
        ):
            raise ConfigurationError(f"{key}: {_shown(value)} is not [first, last] with {lo} <= first <= last <= {hi}")


def int_list(settings: Mapping[str, Any], key: str, lo: int, hi: int, choices: Iterable[int] = ()) -> None:
    """``key = [a, b, ...]``: a non-empty list of integers within lo..hi (and among ``choices`` if given)."""
    if key in settings:
        value = settings[key]
        allowed = set(choices)
        if (
            not isinstance(value, list)
            or not value
            or not all(_is_int(v) and lo <= v <= hi and (not allowed or v in allowed) for v in value)
        ):
            among = f" among {sorted(allowed)}" if allowed else ""
            raise ConfigurationError(f"{key}: {_shown(value)} is not a list of integers in {lo}..{hi}{among}")


def sub_table(settings: Mapping[str, Any], key: str) -> Mapping[str, Any]:
    value = settings.get(key, {})
    if not isinstance(value, Mapping):
        raise ConfigurationError(f"{key}: {_shown(value)} is not a table")
    return value


def no_table() -> Mapping[Any, Any]:
    """The default of a settings field holding a table (``field(default_factory=no_table)``): empty, read-only."""
    return MappingProxyType({})


def frozen(value: object) -> object:
    """A TOML value made immutable: lists become tuples, tables read-only mappings (deeply)."""
    if isinstance(value, list):
        return tuple(frozen(v) for v in value)
    if isinstance(value, Mapping):
        return MappingProxyType({k: frozen(v) for k, v in value.items()})
    return value


def build(cls: type[T], settings: Mapping[str, Any], **parsed: object) -> T:
    """The frozen dataclass ``cls`` of a checked table: each key present sets the field of its name (made
    immutable by :func:`frozen`, or the value given in ``parsed`` for a key the plugin converted itself);
    an absent key keeps the field's default, the only one. A key that is not a field is an error naming it."""
    fields = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]
    known_keys(settings, fields)
    values = {key: parsed[key] if key in parsed else frozen(value) for key, value in settings.items()}
    return cls(**values)
