"""Options of a plugin's simulator front ends and decoder, declared as data (no argparse in the contract).

A plugin lists :class:`PluginOption` objects in ``simulator_options`` / ``decoder_options``; the command line
maps them to its own flags (namespaced per plugin), and Python code passes the same names in a plain mapping::

    plugin.start_simulator({"port": "PTY"}, {1: starter})

:func:`resolve_options` turns such a mapping into :class:`OptionValues`: unknown names are refused, text is
converted with the option's ``type``, choices are checked and defaults filled, every error naming the option.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass

from starterbus.core.errors import ConfigurationError


@dataclass(frozen=True, slots=True)
class PluginOption:
    """One option of a simulator front end or a decoder.

    ``name``: the key in the options mapping (a Python identifier). ``type``: converts command-line text
    (``int``, ``float``, ``str``, any ``str -> value`` callable); ``bool`` makes a switch (given: True).
    ``multiple``: the option may be repeated; its value is a list. ``flag``: the command-line flag, by default
    ``--PLUGIN-NAME`` (the plugin's name, then the option's, ``_`` as ``-``); a flag declared explicitly is kept
    exactly, and another plugin declaring it is refused. ``aliases``: extra flags added only while no one else
    holds them.
    """

    name: str
    type: Callable[[str], object] = str
    help: str = ""
    default: object = None
    multiple: bool = False
    choices: tuple[object, ...] | None = None
    flag: str | None = None
    metavar: str | None = None
    required: bool = False
    aliases: tuple[str, ...] = ()

    @property
    def is_switch(self) -> bool:
        return self.type is bool

    def flag_for(self, plugin: str) -> str:
        return self.flag or f"--{plugin}-{self.name.replace('_', '-')}"

    def convert(self, value: object) -> object:
        """``value`` as this option's type (text is converted; a value of the right kind is kept)."""
        if self.is_switch:
            if isinstance(value, bool):
                return value
            raise ConfigurationError(f"option {self.name!r}: {value!r} is not true or false")
        if isinstance(value, str) and self.type is not str:
            try:
                value = self.type(value)
            except (ValueError, TypeError, ConfigurationError) as exc:
                raise ConfigurationError(f"option {self.name!r}: {value!r} is not valid ({exc})") from None
        if self.choices is not None and value not in self.choices:
            known = ", ".join(map(str, self.choices))
            raise ConfigurationError(f"option {self.name!r}: {value!r} is not one of {known}")
        return value


#: the name the issue used; the same class
SimOption = PluginOption


class OptionValues(Mapping[str, object]):
    """Resolved option values (defaults filled) and which of them were given; typed getters for plugins."""

    def __init__(self, values: Mapping[str, object], given: frozenset[str]) -> None:
        self._values = dict(values)
        self.given = given

    def __getitem__(self, name: str) -> object:
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def text(self, name: str) -> str | None:
        value = self._values[name]
        return None if value is None else str(value)

    def integer(self, name: str) -> int | None:
        value = self._values[name]
        return None if value is None else int(value)  # type: ignore[call-overload]

    def number(self, name: str) -> float | None:
        value = self._values[name]
        return None if value is None else float(value)  # type: ignore[arg-type]

    def integers(self, name: str) -> list[int]:
        value = self._values[name]
        return [int(v) for v in value] if isinstance(value, (list, tuple)) else []

    def switch(self, name: str) -> bool:
        return bool(self._values[name])


def resolve_options(declared: Sequence[PluginOption], given: Mapping[str, object], what: str = "") -> OptionValues:
    """Check ``given`` against ``declared``: unknown names refused, values converted and checked, defaults filled.

    ``what`` names the plugin in errors (``"acme simulator"``). An option whose value is None counts as
    not given (the command line's way of saying so).
    """
    by_name = {option.name: option for option in declared}
    where = f"{what}: " if what else ""
    unknown = sorted(set(given) - set(by_name))
    if unknown:
        known = ", ".join(sorted(by_name)) or "none"
        raise ConfigurationError(f"{where}unknown option(s) {', '.join(unknown)} (known: {known})")
    values: dict[str, object] = {}
    present: set[str] = set()
    for name, option in by_name.items():
        value = given.get(name)
        if value is None:
            if option.required:
                raise ConfigurationError(f"{where}option {name!r} is required")
            values[name] = ([] if option.multiple else None) if option.default is None else option.default
            if option.is_switch and option.default is None:
                values[name] = False
            continue
        present.add(name)
        try:
            if option.multiple:
                items = value if isinstance(value, (list, tuple)) else [value]
                values[name] = [option.convert(v) for v in items]
            else:
                values[name] = option.convert(value)
        except ConfigurationError as exc:
            raise ConfigurationError(f"{where}{exc}") from None
    return OptionValues(values, frozenset(present))


__all__ = ["OptionValues", "PluginOption", "SimOption", "resolve_options"]
