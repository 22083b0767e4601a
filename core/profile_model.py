"""The device profile as loaded: :class:`Profile` (one model's points, enums, faults, roles and per-space
tables), its :class:`ControlTraits`, and the manual addresses it is looked up by (:func:`normalise_address`).

The loader that builds one from a TOML file, checking every rule, is :mod:`starterbus.core.profile`, which
re-exports these names.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

from starterbus.core.address_space import parser_of, space_of
from starterbus.core.entry import nearest
from starterbus.core.errors import ConfigurationError, ProfileError, StarterbusError, UnknownPointError
from starterbus.core.model import EnumTable, Kind, PointDef, Provenance
from starterbus.core.profile_points import key_text, shown
from starterbus.core.status import FaultTable

S = TypeVar("S")


@dataclass(frozen=True, slots=True)
class ControlTraits:
    bus_control_required: bool = False
    bit12_is_mains_voltage: bool = False
    write_protect_key: str = ""
    locked_while_running: frozenset[str] = frozenset()
    #: the parameter saying where start/stop commands come from ("" = the profile names none)
    source_key: str = ""
    #: its codes under which the bus may command, bus alone first (the simulated starter's setting)
    source_bus_codes: tuple[int, ...] = ()


@dataclass(frozen=True, slots=True)
class Profile:
    """One device model: its points, enums, faults, roles and per-transport facts."""

    name: str
    vendor: str
    display_name: str
    address_style: str  # "register" or "index"
    points: Mapping[str, PointDef]
    enums: Mapping[str, EnumTable]
    faults: FaultTable
    control: ControlTraits
    roles: Mapping[str, Any]  # role -> key (phase_currents -> list of keys)
    #: address space -> its ``[transports.NAME]`` table, read-only, ``exceptions`` / ``errors`` parsed into
    #: code -> Label (typed settings: :meth:`settings_for`)
    spaces: Mapping[str, Mapping[str, Any]]
    manuals: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    source: str = ""
    fault_sources: Mapping[int, Provenance] = field(default_factory=dict)  # fault code -> where it comes from
    #: the overlays (``starterbus.overlays`` entry points) that added address spaces to the model as shipped
    overlays: tuple[str, ...] = ()
    _by_address: Mapping[tuple[Kind | None, str], str] = field(default_factory=dict, repr=False)
    #: address space -> the typed object its parser's ``parse_settings`` made of the table (opaque to the core)
    _settings: dict[str, object] = field(default_factory=dict, repr=False, compare=False)

    # -- lookup ---------------------------------------------------------------------------------------------

    @property
    def parameters(self) -> list[PointDef]:
        return [p for p in self.points.values() if p.kind is Kind.PARAMETER]

    @property
    def measurements(self) -> list[PointDef]:
        return [p for p in self.points.values() if p.kind is Kind.MEASUREMENT]

    def point(self, key_or_address: str) -> PointDef:
        """A point by snake_case key or by the manual's own address ("0x0103", "p7", "m3").

        JJR8000-style addresses read as the manual prints them: parameter indexes (appendix 3) in decimal,
        measurement addresses (appendix 2) in hex, so ``m10`` is 0x10 (last fault code), ``p10`` index 10.
        """
        text_in = str(key_or_address).strip()
        found = self.points.get(text_in) or self.points.get(text_in.lower())
        if found is not None:
            return found
        norm = normalise_address(text_in, self.address_style)
        if norm is not None:
            key = self._by_address.get(norm) or self._by_address.get((None, norm[1]))
            if key is not None:
                return self.points[key]
        close = nearest(text_in, self.points)
        hint = f"did you mean {', '.join(close)}? " if close else ""
        example = " like 0x0100" if self.address_style == "register" else " like p7 or m3"
        raise UnknownPointError(
            f"{self.name}: no parameter or measurement {shown(key_or_address)} ({hint}use a key or a manual "
            f"address{example}; `starterbus params {self.name}` lists them)"
        )

    def role(self, name: str) -> PointDef | None:
        key = self.roles.get(name)
        return self.points[key] if isinstance(key, str) else None

    def phase_currents(self) -> list[PointDef]:
        return [self.points[k] for k in self.roles.get("phase_currents", [])]

    @property
    def transports(self) -> Mapping[str, Mapping[str, Any]]:
        """Deprecated name of :attr:`spaces` (its keys are address spaces, not transport names)."""
        return self.spaces

    def supports(self, transport: str) -> bool:
        """True when the model has the address space ``transport`` (a space or a transport plugin's name) speaks."""
        return space_of(transport) in self.spaces

    def transport_settings(self, transport: str) -> Mapping[str, Any]:
        """The table of the address space ``transport`` (a space or a transport's name) names: read-only, as the
        file writes it except ``exceptions`` / ``errors``, whose keys are parsed to integers and entries to
        :class:`Label`. For display; a transport reads its typed settings with :meth:`settings_for`."""
        return self.spaces.get(space_of(transport), {})

    def settings_for(self, transport: str, kind: type[S]) -> S:
        """The typed settings object the parser of the address space ``transport`` names (the space, or a
        transport that speaks it) made of its table when the profile loaded (``AddressSpace.parse_settings``, or
        the plugin's for a plugin that is its own space; parsed now for a profile loaded before the parser was
        installed). ``kind`` is the parser's own class: anything else is a ConfigurationError."""
        space = space_of(transport)
        value = self._settings.get(space)
        if value is None:
            parser = parser_of(space)
            if parser is None:
                raise ConfigurationError(f"{self.name}: nothing installed parses the {space} address space")
            try:
                value = parser.parse_settings(self.transport_settings(space))
            except StarterbusError as exc:
                raise ProfileError(self.source or self.name, f"transports.{key_text(space)}", str(exc)) from None
            self._settings[space] = value
        if not isinstance(value, kind):
            raise ConfigurationError(
                f"{self.name}: the {space} settings are a {type(value).__name__}, not a {kind.__name__}"
            )
        return value

    def by_protocol_address(self, transport: str, kind: Kind, address: object) -> PointDef | None:
        space = space_of(transport)
        for point in self.points.values():
            if point.kind is kind and point.addresses.get(space) == address:
                return point
        return None

    def no_interface(self, transport: str) -> str:
        """Why ``transport`` cannot serve this model, for an error message."""
        space = space_of(transport)
        speaks = f" (it speaks the {space} address space)" if space != transport else ""
        return (
            f"{self.display_name} has no {transport} interface{speaks}; its address spaces: "
            f"{', '.join(sorted(self.spaces))}"
        )


def normalise_address(text: str, style: str) -> tuple[Kind | None, str] | None:
    """A manual address as (kind or None, number as text), or None if ``text`` is not one.

    "index" style: ``p<N>`` decimal (appendix 3 counts 0-118), ``m<N>`` hex as appendix 2 prints it
    (``m0a``, ``m10`` = 0x10); a ``0x`` prefix is hex for both. "register" style: ``0x0103``, ``0103``, ``103h``.
    """
    t = text.strip().lower()
    if style == "index":
        m = re.fullmatch(r"([pm])\s*(0x[0-9a-f]{1,8}|[0-9a-f]{1,8})", t)
        if m is None:
            return None
        number = m.group(2)
        if m.group(1) == "p":
            if not (number.startswith("0x") or number.isdigit()):
                return None
            value = int(number, 16) if number.startswith("0x") else int(number, 10)
            return Kind.PARAMETER, str(value)
        return Kind.MEASUREMENT, str(int(number, 16))
    m = re.fullmatch(r"(?:0x)?([0-9a-f]{1,4})h?", t)
    if m is None or not (t.startswith("0x") or t.endswith("h") or len(m.group(1)) == 4):
        return None
    return None, str(int(m.group(1), 16))


__all__ = ["ControlTraits", "Profile", "normalise_address"]
