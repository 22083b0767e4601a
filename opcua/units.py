"""Profile units as OPC UA EUInformation (UNECE Recommendation 20 common codes, OPC 10000-8 5.6.3)."""

from __future__ import annotations

from asyncua import ua

UNECE_NAMESPACE = "http://www.opcfoundation.org/UA/units/un/cefact"
#: units without a UNECE code: OPC 10000-8 says UnitId -1 means "no unit id available"
LOCAL_NAMESPACE = "urn:starterbus:units"

#: profile unit -> (UNECE common code, description); the display name is the profile's own unit text
UNECE: dict[str, tuple[str, str]] = {
    "A": ("AMP", "ampere"),
    "V": ("VLT", "volt"),
    "s": ("SEC", "second"),
    "min": ("MIN", "minute"),
    "h": ("HUR", "hour"),
    "%": ("P1", "percent"),
    "Hz": ("HTZ", "hertz"),
    "kW": ("KWT", "kilowatt"),
    "°C": ("CEL", "degree Celsius"),
}

#: units the profiles use that UNECE has no code for
LOCAL: dict[str, str] = {
    "x In": "multiple of the motor rated current (In)",
    "cycles": "mains periods",
}


def unit_id(code: str) -> int:
    """The UNECE common code packed one ASCII byte per character, big-endian (``AMP`` -> 4279632)."""
    value = 0
    for char in code:
        value = (value << 8) | ord(char)
    return value


def eu_information(unit: str) -> ua.EUInformation | None:
    """EUInformation for a profile unit; None for a unitless point ("")."""
    if not unit:
        return None
    if unit in UNECE:
        code, description = UNECE[unit]
        return ua.EUInformation(
            NamespaceUri=UNECE_NAMESPACE,
            UnitId=unit_id(code),
            DisplayName=ua.LocalizedText(unit, "en"),
            Description=ua.LocalizedText(description, "en"),
        )
    return ua.EUInformation(
        NamespaceUri=LOCAL_NAMESPACE,
        UnitId=-1,
        DisplayName=ua.LocalizedText(unit, "en"),
        Description=ua.LocalizedText(LOCAL.get(unit, unit), "en"),
    )
