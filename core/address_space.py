"""Address spaces: what a model's points are addressed by, whichever transport carries the request.

A model describes each of its address spaces once (a ``[transports.NAME]`` table and a ``NAME = ...`` field per
point); a transport plugin declares the space it speaks (``TransportPlugin.address_space``), and every transport
that speaks a space serves every model that has it. Spaces are registered through the
``starterbus.address_spaces`` entry-point group: the :class:`AddressSpace` parses the model's table into typed
settings and each point's address. A plugin that declares no space is a space of its own name (the plugin
parses its table and its addresses, as before address spaces existed).

A table or a point field may name the space, or a transport that speaks it (``modbus-rtu`` stands for the
``modbus`` space its plugin declares): profiles written before address spaces load unchanged.

The registries of the installed spaces and transport plugins live here, below the model and the profile loader
that resolve names and parse addresses with them (docs/architecture.md, "Inside core"); a plugin is seen here
only as what it offers the spaces (:class:`SpaceSpeaker`).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import Any, Protocol

from starterbus.core.entry_points import Registry
from starterbus.core.errors import ConfigurationError, PluginError, StarterbusError

TRANSPORT_GROUP = "starterbus.transports"
SPACE_GROUP = "starterbus.address_spaces"


class SpaceParser(Protocol):
    """What parses one address space of a model: an :class:`AddressSpace`, or a plugin that is its own space."""

    name: str
    requires_point_addresses: bool

    def parse_address(self, value: object) -> Any: ...

    def parse_settings(self, settings: Mapping[str, Any]) -> object: ...


class SpaceSpeaker(SpaceParser, Protocol):
    """A transport plugin as the address spaces see it: the space it speaks ("": one of its own name). The
    plugin API (:class:`~starterbus.core.plugin.TransportPlugin`, above this module) is one."""

    address_space: str


class AddressSpace:
    """One address space (Modbus holding registers, PKW parameter numbers, CANopen objects...).

    Subclass it, set :attr:`name`, and override :meth:`parse_address` and :meth:`parse_settings`; register the
    instance in the ``starterbus.address_spaces`` entry-point group under the same name.
    """

    name: str = ""
    summary: str = ""
    #: True when a model that has this space must give some of its points an address in it
    requires_point_addresses: bool = True

    def parse_address(self, value: object) -> Any:
        """A point's address in this space, from its ``NAME = ...`` field; the default: an integer 0..0xFFFF."""
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= 0xFFFF:
            raise ConfigurationError(f"{value!r} is not an address (an integer 0..0xFFFF)")
        return value

    def parse_settings(self, settings: Mapping[str, Any]) -> object:
        """The model's ``[transports.NAME]`` table as a typed, frozen object (default: the table, read-only)."""
        return MappingProxyType(dict(settings))


def _to_space(name: str, obj: object) -> AddressSpace:
    if isinstance(obj, type) and issubclass(obj, AddressSpace):
        obj = obj()
    if not isinstance(obj, AddressSpace):
        raise PluginError(f"entry point {name!r} gives {obj!r}, not an AddressSpace")
    if obj.name != name:
        raise PluginError(f"entry point {name!r} gives an address space that calls itself {obj.name!r}")
    return obj


_transport_checks: list[Callable[[str, object], SpaceSpeaker]] = []


def check_transports_with(check: Callable[[str, object], SpaceSpeaker]) -> None:
    """How an entry point of the transports group becomes a plugin: given by the plugin API when it is imported
    (it knows the ``TransportPlugin`` class, which sits above this module)."""
    _transport_checks[:] = [check]


def _to_transport(name: str, obj: object) -> SpaceSpeaker:
    if not _transport_checks:
        # the plugin API was never imported, so what the entry point gave cannot be a TransportPlugin
        raise PluginError(f"entry point {name!r} gives {obj!r}, not a TransportPlugin")
    return _transport_checks[0](name, obj)


_lock = threading.Lock()
_space_of: dict[str, str] = {}


def forget() -> None:
    """Forget what names were resolved to (the registries were rescanned)."""
    with _lock:
        _space_of.clear()


#: the installed address spaces (``starterbus.address_spaces``)
address_spaces: Registry[AddressSpace] = Registry(SPACE_GROUP, _to_space, forget)
#: the installed transport plugins (``starterbus.transports``), each checked by the plugin API; the registry
#: (:mod:`starterbus.core.registry`) hands them out typed as what they are, ``TransportPlugin``
transports: Registry[SpaceSpeaker] = Registry(TRANSPORT_GROUP, _to_transport, forget)


def registered_space(name: str) -> AddressSpace | None:
    """The ``starterbus.address_spaces`` entry of that name, or None (not registered, or it fails to load)."""
    if name not in address_spaces.names():
        return None
    try:
        return address_spaces.get(name)
    except StarterbusError:
        return None


def _plugin(name: str) -> SpaceSpeaker | None:
    try:
        return transports.get(name)
    except StarterbusError:
        return None


def space_of(name: str) -> str:
    """The address space ``name`` means: a registered space is itself, a transport plugin stands for the
    space it speaks, anything else (a plugin not installed) for a space of its own name."""
    found = _space_of.get(name)
    if found is not None:
        return found
    if name in address_spaces.names():
        space = name
    else:
        plugin = _plugin(name)
        space = (plugin.address_space or plugin.name) if plugin is not None else name
    with _lock:
        _space_of[name] = space
    return space


def parser_of(space: str) -> SpaceParser | None:
    """What parses the tables and addresses of ``space``: its registered :class:`AddressSpace`, else the plugin
    of that name (a plugin that is its own space); None when neither is installed (nothing is checked)."""
    registered = registered_space(space)
    if registered is not None:
        return registered
    plugin = _plugin(space)
    if plugin is not None and (plugin.address_space or plugin.name) == space:
        return plugin
    return None


def speakers(space: str) -> list[str]:
    """The installed transport plugins that speak ``space`` (those that fail to load are left out)."""
    names = []
    for name in transports.names():
        plugin = _plugin(name)
        if plugin is not None and (plugin.address_space or plugin.name) == space:
            names.append(name)
    return names


__all__ = [
    "SPACE_GROUP",
    "TRANSPORT_GROUP",
    "AddressSpace",
    "SpaceParser",
    "SpaceSpeaker",
    "address_spaces",
    "check_transports_with",
    "forget",
    "parser_of",
    "registered_space",
    "space_of",
    "speakers",
    "transports",
]
