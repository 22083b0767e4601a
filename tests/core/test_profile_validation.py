"""Profile loading rejects every inconsistency with an error naming the file and the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from starterbus.core.errors import ProfileError, UnknownPointError
from starterbus.core.profile import load_profile_text

BASE = (Path(__file__).parent / "toy_profile.toml").read_text(encoding="utf-8")


def test_base_loads_and_resolves_manual_addresses() -> None:
    profile = load_profile_text(BASE, "toy.toml")
    assert profile.point("limit").raw_min == 150
    assert profile.point("0x0103").key == "limit"
    assert profile.point("0x103").key == "limit"
    assert profile.point("0103").key == "limit"
    with pytest.raises(UnknownPointError, match="0x0104"):
        profile.point("0x0104")


@pytest.mark.parametrize(
    ("mutation", "key", "message"),
    [
        (('key = "limit"', 'key = "rated"'), "parameters.rated", "duplicate key"),
        (("modbus-rtu = 0x0103", "modbus-rtu = 0x0100"), "parameters.limit", "overlaps rated"),
        (("min = 150\nmax = 500", "min = 500\nmax = 150"), "parameters.limit.min", "inverted range"),
        (('unit = "%"', 'unit = "%"\nenum = "F9"'), "parameters.limit.enum", "unknown enum 'F9'"),
        (('current_limit = "limit"', 'current_limit = "nope"'), "roles.current_limit", "names no point"),
        (('address = "0x0103"', 'address = "0x0100"'), "parameters.limit.address", "also the address"),
        (("schema = 1", "schema = 2"), "schema", "expected schema"),
        (('key = "limit"', 'key = "Limit"'), "parameters[1].key", "snake_case"),
        (('unit = "%"', 'unit = "%"\ncolour = 3'), "parameters.limit", "unknown field"),
    ],
)
def test_invalid_profiles_name_file_and_key(mutation: tuple[str, str], key: str, message: str) -> None:
    old, new = mutation
    assert old in BASE
    text = BASE.replace(old, new, 1) if old != 'key = "limit"' else BASE.replace(old, new)
    with pytest.raises(ProfileError) as info:
        load_profile_text(text, "toy.toml")
    assert info.value.source == "toy.toml"
    assert info.value.key == key
    assert message in str(info.value)
    assert str(info.value).startswith(f"toy.toml: {key}: ")


def test_toml_syntax_error_names_the_file() -> None:
    with pytest.raises(ProfileError, match=r"^broken.toml: \(toml\)"):
        load_profile_text("schema = = 1", "broken.toml")
