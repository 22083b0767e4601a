"""Address spaces: what a model's points are addressed by, whichever transport carries the request.

A model describes each of its address spaces once (a ``[transports.NAME]`` table and a ``NAME = ...`` field per
point); a transport plugin declares the space it speaks (``TransportPlugin.address_space``), and every transport
that speaks a space serves every model that has it. Spaces are registered through the
``starterbus.address_spaces`` entry-point group: the :class:`AddressSpace` parses the model's table into typed
settings and each point's address. A plugin that declares no space is a space of its own name (the plugin
parses its table and its addresses, as before address spaces existed).

A table or a point field may name the space, or a transport that speaks it (``modbus-rtu`` stands for the
``modbus`` space its plugin declares): profiles written before address spaces load unchanged.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Protocol

from starterbus.core.errors import ConfigurationError, StarterbusError

if TYPE_CHECKING:
    from starterbus.core.plugin import TransportPlugin


class SpaceParser(Protocol):
    """What parses one address space of a model: an :class:`AddressSpace`, or a plugin that is its own space."""

    name: str
    requires_point_addresses: bool

    def parse_address(self, value: object) -> Any: ...

    def parse_settings(self, settings: Mapping[str, Any]) -> object: ...


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


_lock = threading.Lock()
_space_of: dict[str, str] = {}


def forget() -> None:
    """Forget what names were resolved to (the registries were rescanned)."""
    with _lock:
        _space_of.clear()


def registered_space(name: str) -> AddressSpace | None:
    """The ``starterbus.address_spaces`` entry of that name, or None (not registered, or it fails to load)."""
    from starterbus.core.registry import address_spaces  # late: the registry imports the profile loader

    if name not in address_spaces.names():
        return None
    try:
        return address_spaces.get(name)
    except StarterbusError:
        return None


def _plugin(name: str) -> TransportPlugin | None:
    from starterbus.core.registry import transports

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
    from starterbus.core.registry import address_spaces

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
    from starterbus.core.registry import transports

    names = []
    for name in transports.names():
        plugin = _plugin(name)
        if plugin is not None and (plugin.address_space or plugin.name) == space:
            names.append(name)
    return names


__all__ = ["AddressSpace", "SpaceParser", "forget", "parser_of", "registered_space", "space_of", "speakers"]
