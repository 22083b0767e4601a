"""The ``[transports.devicenet]`` table of a profile, parsed once when the profile loads.

``input_assemblies`` / ``output_assemblies`` are the instance numbers of the model's two assembly sets, in
the order ``[basic, extended]`` (the JJR8000: inputs 1 and 101, outputs 2 and 102; manual 3.2.4, PRO type
P1/M1 and P3/M2). The layouts of the two sets are this plugin's codec (codec/assemblies.py); the numbers a device
gives them are the profile's.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from starterbus.core import ConfigurationError, EncodeError, Profile
from starterbus.core import settings_check as check
from starterbus.transports.devicenet.codec.assemblies import AssemblySet
from starterbus.transports.devicenet.codec.identity import Identity
from starterbus.transports.devicenet.codec.ids import MAX_MAC

NAME = "devicenet"
BITRATES = (125000, 250000, 500000)
_IDENTITY_INTS = {"vendor_id": 0xFFFF, "device_type": 0xFFFF, "product_code": 0xFFFF, "status": 0xFFFF}
_IDENTITY_TEXTS = ("product_name", "product_code_text", "revision_text")  # the last two: documentation only


@dataclass(frozen=True, slots=True)
class DeviceNetSettings:
    """What a model says about its DeviceNet slave (each key's one default here)."""

    mac_ids: tuple[int, int] = (1, MAX_MAC)
    input_assemblies: tuple[int, int] = (1, 101)  # [basic, extended]
    output_assemblies: tuple[int, int] = (2, 102)  # [basic, extended]
    bitrates: tuple[int, ...] = BITRATES
    identity: Identity = field(default_factory=Identity)  # product_name "" until the profile's name fills it

    @classmethod
    def parse(cls, settings: Mapping[str, Any]) -> DeviceNetSettings:
        check.int_range(settings, "mac_ids", 0, MAX_MAC)
        for key in ("input_assemblies", "output_assemblies"):
            check.int_list(settings, key, 1, 0xFFFF)
            if key in settings and (len(settings[key]) != 2 or settings[key][0] == settings[key][1]):
                raise ConfigurationError(f"{key}: {settings[key]!r} is not [basic, extended] (two instance numbers)")
        check.int_list(settings, "bitrates", 1, 1_000_000, choices=BITRATES)
        parsed: dict[str, object] = {}
        if "identity" in settings:
            parsed["identity"] = parse_identity(check.sub_table(settings, "identity"))
        return check.build(cls, settings, **parsed)

    def instances(self, assemblies: AssemblySet) -> tuple[int, int]:
        """The (input, output) instance numbers of one assembly set on this model."""
        i = 0 if assemblies is AssemblySet.BASIC else 1
        return self.input_assemblies[i], self.output_assemblies[i]


def parse_identity(table: Mapping[str, Any]) -> Identity:
    """The identity object's attributes (``[transports.devicenet] identity = {...}``), each checked by name."""
    names = {f"identity.{k}": v for k, v in table.items()}
    check.known_keys(names, [f"identity.{k}" for k in (*_IDENTITY_INTS, "serial_number", "revision", *_IDENTITY_TEXTS)])
    for name, hi in _IDENTITY_INTS.items():
        check.int_value(names, f"identity.{name}", 0, hi)
    check.int_value(names, "identity.serial_number", 0, 0xFFFFFFFF)
    revision = table.get("revision", [1, 1])
    if not isinstance(revision, list) or len(revision) != 2:
        raise ConfigurationError(f"identity.revision: {revision!r} is not [major, minor]")
    for part in revision:
        check.int_value({"identity.revision": part}, "identity.revision", 0, 0xFF)
    for name in _IDENTITY_TEXTS:
        value = table.get(name, "")
        if not isinstance(value, str) or (name == "product_name" and len(value.encode("ascii", "replace")) > 32):
            raise ConfigurationError(f"identity.{name}: {value!r} is not a text (product_name: 32 characters)")
    values = {k: v for k, v in table.items() if k in _IDENTITY_INTS or k in ("serial_number", "product_name")}
    try:
        return Identity(**values, revision=(revision[0], revision[1]))
    except EncodeError as exc:
        raise ConfigurationError(f"identity: {exc}") from None


def profile_identity(profile: Profile, **overrides: Any) -> Identity:
    """The identity in the profile's ``[transports.devicenet] identity`` table (the product name: the model's
    display name if the table gives none), with overrides."""
    base = devicenet_settings(profile).identity
    if not base.product_name:
        base = replace(base, product_name=profile.display_name)
    try:
        return replace(base, **overrides)
    except (TypeError, EncodeError) as exc:
        raise ConfigurationError(f"{profile.name}: invalid DeviceNet identity: {exc}") from exc


def devicenet_settings(profile: Profile) -> DeviceNetSettings:
    return profile.settings_for(NAME, DeviceNetSettings)
