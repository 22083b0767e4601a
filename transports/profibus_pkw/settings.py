"""The ``[transports.profibus-pkw]`` table of a profile, parsed once when the profile loads."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from starterbus.core import ConfigurationError, Label, Profile, Refusal
from starterbus.core import settings_check as check
from starterbus.transports.profibus_pkw.codec.codes import PROTOCOL

#: the refusal key of a task the simulated slave does not support (next to the core's ``Refusal`` names)
UNSUPPORTED_TASK = "unsupported_task"
RESPONSE_2 = "response 2"


@dataclass(frozen=True, slots=True)
class ProfibusSettings:
    """What a model says about its Profibus DP slave (each key's one default here)."""

    ppo: tuple[int, ...] = ()  # the PPO types it offers (1, 3)
    stations: tuple[int, int] = (0, 127)  # its DP addresses
    errors: Mapping[int, Label] = field(default_factory=check.no_table)  # PKW error number -> the manual's text
    #: how the simulated slave refuses: refusal name -> an error number (response 3) or "response 2"
    refusals: Mapping[str, int | str] = field(default_factory=check.no_table)

    @classmethod
    def parse(cls, settings: Mapping[str, Any]) -> ProfibusSettings:
        """Unknown keys and wrong values: ConfigurationError naming them (``errors`` the loader parsed)."""
        check.int_list(settings, "ppo", 1, 3, choices=(1, 3))
        check.int_range(settings, "stations", 0, 127)
        names = {r.name.lower() for r in Refusal} | {UNSUPPORTED_TASK}
        for name, value in check.sub_table(settings, "refusals").items():
            if name not in names:
                raise ConfigurationError(f"refusals.{name}: unknown refusal (known: {', '.join(sorted(names))})")
            if value != RESPONSE_2 and (
                isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFFFF
            ):
                raise ConfigurationError(f"refusals.{name}: {value!r} is not an error number or {RESPONSE_2!r}")
        return check.build(cls, settings)


def profibus_settings(profile: Profile) -> ProfibusSettings:
    return profile.settings_for(PROTOCOL, ProfibusSettings)
