"""Per-transport profile settings: parsed by the plugin into a typed, frozen object when the profile loads."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType
from typing import Any

import pytest

from starterbus.core.errors import ConfigurationError, ProfileError
from starterbus.core.plugin import TransportPlugin
from starterbus.core.profile import Profile, load_profile_text
from starterbus.core.registry import get_profile, get_transport
from starterbus.core.transport import Transport
from starterbus.core.url import DeviceUrl
from starterbus.spaces.modbus import ModbusSettings
from starterbus.transports.devicenet.settings import DeviceNetSettings
from starterbus.transports.modbus.url import ModbusRtuConfig
from starterbus.transports.profibus_pkw.settings import ProfibusSettings

PROFILES = Path(__file__).parents[2] / "core" / "profiles"


def profile_text(model: str) -> str:
    return (PROFILES / f"{model}.toml").read_text(encoding="utf-8")


def test_the_profile_keeps_each_plugin_s_frozen_object() -> None:
    jjr8000 = get_profile("jjr8000")
    modbus = jjr8000.settings_for("modbus-rtu", ModbusSettings)
    assert modbus.max_read_registers == 1 and modbus.unit_ids == (1, 247) and modbus.baudrates[0] == 1200
    assert str(modbus.exceptions[1]).startswith("illegal function")
    with pytest.raises(dataclasses.FrozenInstanceError):
        modbus.max_read_registers = 2  # type: ignore[misc]
    with pytest.raises(TypeError):
        modbus.exceptions[9] = modbus.exceptions[1]  # type: ignore[index]
    assert jjr8000.settings_for("profibus-pkw", ProfibusSettings).stations == (1, 127)
    devicenet = jjr8000.settings_for("devicenet", DeviceNetSettings)
    assert devicenet.input_assemblies == (1, 101) and devicenet.identity.vendor_id == 819
    with pytest.raises(ConfigurationError, match="the modbus settings are a ModbusSettings, not a Profibus"):
        jjr8000.settings_for("modbus-rtu", ProfibusSettings)


def test_each_key_has_one_default() -> None:
    """An absent key reads as the settings class's default, wherever it is read (unit_ids had two)."""
    assert ModbusSettings.parse({}) == ModbusSettings()
    text = profile_text("jjr5000").replace("\nunit_ids = [0, 247]\n", "\n")
    profile = load_profile_text(text, "no-units.toml")
    assert profile.settings_for("modbus-rtu", ModbusSettings).unit_ids == (1, 247)
    assert ModbusRtuConfig.from_url(DeviceUrl.parse("modbus-rtu:///dev/null?unit=247"), profile).unit == 247
    text = profile_text("ssd1")  # unit_ids = [0, 245]: the profile's value, not the default, bounds the URL
    with pytest.raises(ConfigurationError, match=r"slave addresses are 1\.\.245"):
        ModbusRtuConfig.from_url(DeviceUrl.parse("modbus-rtu:///dev/null?unit=246"), load_profile_text(text))


@pytest.mark.parametrize(
    ("old", "new", "error"),
    [
        (
            "\nmax_read_registers = 4\n",
            "\nmax_read_registers = 4\nmax_reads = 2\n",
            r"transports.modbus: max_reads: unknown",
        ),
        ("\nmax_read_registers = 4\n", '\nmax_read_registers = "4"\n', r"max_read_registers: '4' is not an integer"),
        ("\nbaudrates = [2400, 4800, 9600, 19200]\n", "\nbaudrates = [true]\n", r"baudrates: \[True\] is not a list"),
        ("\nppo = [1, 3]\n", "\nppo = [1, 3]\nppos = 1\n", r"profibus-pkw: ppos: unknown setting"),
    ],
)
def test_unknown_keys_and_wrong_values_are_named(old: str, new: str, error: str) -> None:
    text = profile_text("jjr5000")
    assert old in text
    with pytest.raises(ProfileError, match=error):
        load_profile_text(text.replace(old, new, 1), "bad.toml")


def test_devicenet_settings_are_checked() -> None:
    text = profile_text("jjr8000")
    for old, new, error in (
        ("input_assemblies = [1, 101]", "input_assemblies = [1, 101, 103]", r"input_assemblies: \[1, 101, 103\]"),
        ("vendor_id = 819", 'vendor_id = "819"', r"identity.vendor_id: '819' is not an integer"),
        ("vendor_id = 819", "vendor = 819", r"identity.vendor: unknown setting"),
    ):
        assert old in text
        with pytest.raises(ProfileError, match=error):
            load_profile_text(text.replace(old, new, 1), "bad.toml")


class _CheckOnly(TransportPlugin):
    """A plugin written before parse_settings: it only checks."""

    name = "check-only"

    def open(self, url: DeviceUrl, profile: Profile) -> Transport:
        raise NotImplementedError

    def check_settings(self, settings: Mapping[str, Any]) -> None:
        if "bad" in settings:
            raise ConfigurationError("bad: refused")


def test_a_plugin_with_only_check_settings_gets_a_read_only_table() -> None:
    plugin = _CheckOnly()
    parsed = plugin.parse_settings({"nodes": [1, 2]})
    assert isinstance(parsed, MappingProxyType) and parsed["nodes"] == [1, 2]
    with pytest.raises(ConfigurationError, match="bad: refused"):
        plugin.parse_settings({"bad": 1})
    modbus = get_transport("modbus-rtu")
    modbus.check_settings({"max_read_registers": 3})  # the built-ins keep the old name as a thin shim
    with pytest.raises(ConfigurationError, match="unit: unknown setting"):
        modbus.check_settings({"unit": 3})
