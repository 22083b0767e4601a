"""Point addresses are an open table keyed by the transport plugin's name; core knows no protocol."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from starterbus.core.errors import ConfigurationError, ProfileError
from starterbus.core.model import Kind
from starterbus.core.profile import load_profile_text
from starterbus.core.simulator import SimulatedStarter
from starterbus.fleet.config import parse_fleet

ROOT = Path(__file__).resolve().parents[2]
BASE = (Path(__file__).parent / "toy_profile.toml").read_text(encoding="utf-8")  # as test_profile_validation


def test_a_transport_that_is_not_installed_keeps_its_addresses_in_any_shape() -> None:
    text = BASE.replace("[transports.modbus-rtu]", "[transports.acme-can]\n[transports.modbus-rtu]")
    text = text.replace("modbus-rtu = 0x0103", "modbus-rtu = 0x0103\nacme-can = [0x2000, 7]")
    profile = load_profile_text(text, "toy.toml")
    limit = profile.point("limit")
    assert limit.address_for("acme-can") == (0x2000, 7) and limit.address_for("modbus-rtu") == 0x0103
    assert SimulatedStarter(profile).point_at("modbus-rtu", Kind.PARAMETER, 0x0103).key == "limit"


def test_a_field_for_a_transport_the_profile_does_not_name_is_unknown() -> None:
    with pytest.raises(ProfileError, match=r"unknown field\(s\) \['acme-can'\].*modbus-rtu"):
        load_profile_text(BASE.replace("modbus-rtu = 0x0103", "modbus-rtu = 0x0103\nacme-can = 5"), "toy.toml")


def test_the_installed_plugin_parses_its_own_addresses() -> None:
    with pytest.raises(ProfileError, match=r"toy.toml: parameters.limit.modbus-rtu: 'x' is not an address"):
        load_profile_text(BASE.replace("modbus-rtu = 0x0103", 'modbus-rtu = "x"'), "toy.toml")


def test_a_fleet_address_goes_where_the_plugin_says() -> None:
    fleet = """
[[bus]]
name = "dp"
url = "profibus-pkw+gateway://127.0.0.1:5020"
  [[bus.device]]
  name = "crusher"
  model = "jjr8000"
  address = 4
  options = { ppo = 1 }
"""
    device = parse_fleet(fleet, "f.toml").devices[0]
    assert "station=4" in device.url  # Profibus: the DP station, checked against the model's range
    with pytest.raises(ConfigurationError, match=r"options.station.*address = \.\.\."):
        parse_fleet(fleet.replace("options = { ppo = 1 }", "options = { ppo = 1, station = 4 }"), "f.toml")


def test_core_names_no_protocol() -> None:
    """The open core: protocol names appear in core only in comments and docstrings that explain the contract."""
    found = subprocess.run(["grep", "-riE", "modbus|profibus|devicenet", *map(str, (ROOT / "core").glob("*.py"))],
                           capture_output=True, text=True, check=False).stdout.splitlines()  # fmt: skip
    code = [line for line in found if not re.match(r"^\S+:\s*(#|[A-Z`(]|.*\"\"\"|on |clock|.*``)", line)]
    assert code == [], code
