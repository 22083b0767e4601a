"""The plugin object a ``starterbus.transports`` entry point resolves to, and what its optional hooks return.

Import these names from :mod:`starterbus.core`. The plugin sits above the transport it opens
(:mod:`starterbus.core.transport_template`) and the profile it reads; the transports registry below the profile loader
(:mod:`starterbus.core.address_space`) takes an entry point's object for a plugin only through
:func:`_to_transport`, handed down here.
"""

from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from starterbus.core.address_space import check_transports_with
from starterbus.core.errors import ConfigurationError, PluginError, UnsupportedOperationError
from starterbus.core.plugin_options import PluginOption
from starterbus.core.profile import Profile
from starterbus.core.url import DeviceUrl

if TYPE_CHECKING:
    import argparse

    from starterbus.core.simulator import SimulatedStarter
    from starterbus.core.transport_template import Capability, Transport


@dataclass(frozen=True, slots=True)
class Annotation:
    """One decoded frame/telegram for the ``decode`` command: a title, annotated fields, and an error if bad."""

    title: str
    fields: list[tuple[str, str, str]] = field(default_factory=list)  # (field, raw, meaning)
    error: str | None = None

    def as_json(self) -> dict[str, object]:
        return {
            "title": self.title,
            "fields": [{"field": f, "raw": r, "meaning": m} for f, r, m in self.fields],
            "error": self.error,
        }


class RunningSimulator(ABC):
    """A protocol front end serving simulated starters, started by ``starterbus simulate``."""

    @abstractmethod
    def describe(self) -> list[str]:
        """Lines to print: where a client connects (e.g. ``modbus-rtu: /dev/pts/4``)."""

    @abstractmethod
    def close(self) -> None: ...

    def client_urls(self) -> dict[int, str]:
        """Device address (unit, MAC, station) -> the URL a client in this process uses to reach it."""
        return {}


class TransportPlugin(ABC):
    """What a ``starterbus.transports`` entry point resolves to."""

    name: str = ""
    summary: str = ""
    #: everything this transport can do at best (a given URL may offer less)
    capabilities: frozenset[Capability] = frozenset()
    #: URL forms, for help texts
    url_forms: tuple[str, ...] = ()

    @abstractmethod
    def open(self, url: DeviceUrl, profile: Profile) -> Transport:
        """Build a transport (not yet opened) for one device. Validate the URL here: bad URL, clear error."""

    #: the address space this transport speaks (``starterbus.address_spaces``, e.g. ``"modbus"``): it serves
    #: every model that has that space. "" (the default): a space of the plugin's own name, whose table and
    #: point addresses this plugin parses (:meth:`parse_settings`, :meth:`parse_address`)
    address_space: str = ""
    #: True when a profile naming this transport must give some of its points an address on it
    requires_point_addresses: bool = False
    #: the URL query parameter a fleet file's ``address`` of a device on this transport fills (None: it takes none)
    address_parameter: str | None = None
    #: the URL query parameter that tells the transport the fleet's poll period, s (a scanner that polls on its
    #: own then polls at the rate asked); None: the transport polls only when asked
    period_parameter: str | None = None

    def parse_address(self, value: object) -> Any:
        """A point's address on this transport, from the profile field named after the plugin (``NAME = ...``).

        Any shape the transport needs (an integer, ``(index, subindex)``, text); raise
        :class:`~starterbus.core.errors.ConfigurationError` naming the value. The default: an integer 0..0xFFFF.
        """
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= 0xFFFF:
            raise ConfigurationError(f"{value!r} is not an address (an integer 0..0xFFFF)")
        return value

    def parse_settings(self, settings: Mapping[str, Any]) -> object:
        """Parse this transport's table of a profile (``[transports.NAME]``) when the profile loads.

        Return a typed, frozen object (a frozen dataclass of your own, one default per key: build it with
        :func:`~starterbus.core.settings_check.build`); the profile keeps it and your transport gets it back
        with ``profile.settings_for(NAME, YourSettings)``. Raise
        :class:`~starterbus.core.errors.ConfigurationError` naming an unknown key or a wrong value; the loader
        adds the file. The default (for plugins written before this hook): :meth:`check_settings`, then the
        table itself, read-only.
        """
        self.check_settings(settings)
        return MappingProxyType(dict(settings))

    def check_settings(self, settings: Mapping[str, Any]) -> None:
        """Check the table without parsing it (the older hook; :meth:`parse_settings` calls it by default).

        A plugin that defines :meth:`parse_settings` need not define this; the built-in ones keep it as
        a shim that parses and drops the result. The default accepts anything.
        """

    # -- optional hooks: simulator front ends and a decoder, declared as data -----------------------------------

    #: options of this plugin's ``starterbus simulate`` front ends (flags ``--NAME-OPTION`` unless declared)
    simulator_options: tuple[PluginOption, ...] = ()
    #: options of ``starterbus decode NAME`` (the frames themselves are given by the caller)
    decoder_options: tuple[PluginOption, ...] = ()
    #: a text shown under ``starterbus decode NAME --help`` (the frame syntax, for instance)
    decoder_help: str = ""

    def start_simulator(
        self, options: Mapping[str, object], starters: Mapping[int, SimulatedStarter]
    ) -> list[RunningSimulator]:
        """Start the front ends ``options`` ask for, serving ``starters`` (address -> starter, shared by every
        front end); return ``[]`` when none of this plugin's options is given.

        ``options`` maps the names of :attr:`simulator_options` to values (text is converted); check them with
        :func:`~starterbus.core.plugin_options.resolve_options`. Errors are
        :class:`~starterbus.core.errors.ConfigurationError` naming the option.
        """
        return []

    def decode(self, frames: Sequence[str], options: Mapping[str, object], profile: Profile | None) -> list[Annotation]:
        """Annotate ``frames`` (one text per frame or hex chunk, as the user gave them) with ``options``
        (names of :attr:`decoder_options`); ``profile`` names points and scales values when given."""
        raise UnsupportedOperationError(f"transport {self.name!r} has no decoder")

    @property
    def has_decoder(self) -> bool:
        return type(self).decode is not TransportPlugin.decode

    # -- deprecated: the argparse hooks of starterbus < 0.x; the CLI still honours them --------------------------

    def add_simulator_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Deprecated (use :attr:`simulator_options`): add ``starterbus simulate`` options to the shared parser."""

    def start_simulators(
        self, args: argparse.Namespace, profile: Profile, starters: Sequence[object]
    ) -> list[RunningSimulator]:
        """Deprecated (use :meth:`start_simulator`): start front ends from the parsed command line.

        ``args.unit`` holds the addresses, ``starters`` the simulated starters in that order, ``profile`` the
        first one's model.
        """
        return []

    def add_decode_arguments(self, parser: argparse.ArgumentParser) -> None:
        """Deprecated (use :attr:`decoder_options`); with it, ``decode(args, profile)`` gets the parsed
        command line, the frames in ``args.data``."""

    @property
    def uses_argparse_simulator(self) -> bool:
        """True for a plugin still written against the deprecated argparse simulator hooks."""
        cls = type(self)
        return (
            cls.add_simulator_arguments is not TransportPlugin.add_simulator_arguments
            or cls.start_simulators is not TransportPlugin.start_simulators
        )

    @property
    def uses_argparse_decoder(self) -> bool:
        """True for a decoder written as the deprecated ``decode(args, profile)``."""
        if not self.has_decoder:
            return False
        try:
            return len(inspect.signature(self.decode).parameters) == 2
        except (TypeError, ValueError):  # pragma: no cover - a builtin or C callable
            return False


def _to_transport(name: str, obj: object) -> TransportPlugin:
    """What a ``starterbus.transports`` entry point gives, as a plugin: an instance, or a class to instantiate."""
    if isinstance(obj, type) and issubclass(obj, TransportPlugin):
        obj = obj()
    if not isinstance(obj, TransportPlugin):
        raise PluginError(f"entry point {name!r} gives {obj!r}, not a TransportPlugin")
    if obj.name != name:
        raise PluginError(f"entry point {name!r} gives a plugin that calls itself {obj.name!r}")
    return obj


check_transports_with(_to_transport)
