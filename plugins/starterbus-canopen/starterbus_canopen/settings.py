"""The profile's ``[transports.canopen]`` table, parsed once when the profile loads (no canopen import here)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from starterbus.core import Profile
from starterbus.core import settings_check as check

PLUGIN_NAME = "canopen"
U32 = 0xFFFFFFFF


@dataclass(frozen=True, slots=True)
class Identity:
    """The identity object 0x1018 (sub-indices 1-4)."""

    vendor_id: int = 0
    product_code: int = 0
    revision: int = 0
    serial_number: int = 0


@dataclass(frozen=True, slots=True)
class CanopenSettings:
    """``node_ids = [lo, hi]``, ``device_type`` (0x1000), ``identity = {...}`` (0x1018); one default per key."""

    node_ids: tuple[int, int] = (1, 127)
    device_type: int = 0
    identity: Identity = field(default_factory=Identity)

    @classmethod
    def parse(cls, settings: Mapping[str, Any]) -> CanopenSettings:
        check.int_range(settings, "node_ids", 1, 127)
        check.int_value(settings, "device_type", 0, U32)
        parsed: dict[str, object] = {}
        if "identity" in settings:
            table = {f"identity.{k}": v for k, v in check.sub_table(settings, "identity").items()}
            names = [f"identity.{f}" for f in Identity.__dataclass_fields__]
            check.known_keys(table, names)
            for name in names:
                check.int_value(table, name, 0, U32)
            parsed["identity"] = Identity(**{k.removeprefix("identity."): v for k, v in table.items()})
        return check.build(cls, settings, **parsed)

    @classmethod
    def of(cls, profile: Profile) -> CanopenSettings:
        return profile.settings_for(PLUGIN_NAME, cls)
