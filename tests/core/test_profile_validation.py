"""Profile loading rejects every inconsistency with an error naming the file and the key."""

from __future__ import annotations

import pytest

from starterbus.core.errors import ProfileError, UnknownPointError
from starterbus.core.profile import load_profile_text

BASE = """
schema = 1
[model]
name = "toy"
address_style = "register"
[roles]
control_word = "control_word"
status_word = "status_word"
phase_currents = ["phase_a_current"]
rated_current = "rated"
current_limit = "limit"
[transports.modbus-rtu]
max_read_registers = 4
[enums.F2]
0 = { en = "disabled", zh = "禁止" }
1 = { en = "enabled", zh = "允许" }
[[measurements]]
key = "control_word"
address = "0x0000"
name_en = "control word"
min = 0
max = 65535
modbus-rtu = 0x0000
[[measurements]]
key = "status_word"
address = "0x0001"
name_en = "status word"
min = 0
max = 65535
modbus-rtu = 0x0001
[[measurements]]
key = "phase_a_current"
address = "0x0002"
name_en = "phase A current"
min = 0
max = 65535
scale = 0.1
unit = "A"
modbus-rtu = 0x0002
[[parameters]]
key = "rated"
address = "0x0100"
name_en = "rated current"
min = 1
max = 1500
unit = "A"
modbus-rtu = 0x0100
[[parameters]]
key = "limit"
address = "0x0103"
name_en = "current limit"
min = 150
max = 500
unit = "%"
modbus-rtu = 0x0103
"""


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
