"""Checks a transport plugin runs on its ``[transports.NAME]`` table of a profile (``check_settings``).

Each raises :class:`ConfigurationError` naming the key and the value; the profile loader adds the file.
Absent keys are fine: the plugin falls back to its defaults.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from typing import Any

from starterbus.core.errors import ConfigurationError


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _shown(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def known_keys(settings: Mapping[str, Any], known: Iterable[str]) -> None:
    allowed = set(known)
    for key in sorted(set(settings) - allowed):
        shown = key if re.fullmatch(r"[\w+-]+", key) else repr(key)
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
