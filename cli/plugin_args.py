"""Plugins' declared options on the command line: one argument group per plugin, clashes reported and skipped.

A plugin's :class:`~starterbus.core.plugin_options.PluginOption` list becomes flags of its own group, with
destinations private to the plugin (``~NAME~OPTION``), so no plugin can overwrite another's values or the
command's own. A plugin whose flag is already held (by the command or by a plugin added before it: the
built-in plugins come first), whose declaration raises, or whose options argparse refuses, is reported on
stderr in one line and left out; the others keep working. Plugins still written against the deprecated argparse
hooks (``add_simulator_arguments`` / ``add_decode_arguments``) go through a thin adapter with the same checks.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from starterbus.core.plugin_options import PluginOption
from starterbus.core.registry import PluginEntry
from starterbus.core.transport import TransportPlugin

TYPED = "typed"
ARGPARSE = "argparse"  # the deprecated hooks


def warn(text: str) -> None:
    print(f"starterbus: warning: {text}", file=sys.stderr, flush=True)


def plugin_order(entries: Iterable[PluginEntry[TransportPlugin]]) -> list[PluginEntry[TransportPlugin]]:
    """Built-in plugins first (their documented flags win a clash), then the others by name."""

    def builtin(entry: PluginEntry[TransportPlugin]) -> bool:
        return all(ep.value.startswith("starterbus.") for ep in entry.entry_points)

    return sorted(entries, key=lambda e: (not builtin(e), e.name))


def _dest(plugin: str, option: str) -> str:
    return f"~{plugin}~{option}"


def _argparse_kwargs(option: PluginOption, plugin: str) -> dict[str, Any]:
    kwargs: dict[str, Any] = {"dest": _dest(plugin, option.name), "default": argparse.SUPPRESS, "help": option.help}
    if option.is_switch:
        kwargs["action"] = "store_true"
        return kwargs
    if option.type is not str:
        kwargs["type"] = option.type
    if option.choices is not None:
        kwargs["choices"] = option.choices
    if option.multiple:
        kwargs["action"] = "append"
    if option.required:
        kwargs["required"] = True
    kwargs["metavar"] = option.metavar or (None if option.choices is not None else option.name.upper())
    if option.default is not None and option.help and "default" not in option.help:
        kwargs["help"] = f"{option.help} (default {option.default})"
    return kwargs


class _Recorder(argparse.ArgumentParser):
    """A scratch parser that remembers the actions a deprecated hook adds."""

    def __init__(self) -> None:
        super().__init__(add_help=False)
        self.recorded: list[argparse.Action] = []

    def add_argument(self, *args: Any, **kwargs: Any) -> argparse.Action:
        action = super().add_argument(*args, **kwargs)
        self.recorded.append(action)
        return action


@dataclass
class OptionMapper:
    """Adds plugins' options to one parser (or one per plugin) and reads their values back."""

    taken_flags: dict[str, str] = field(default_factory=dict)  # flag -> who holds it
    taken_dests: set[str] = field(default_factory=set)
    #: plugin name -> (TYPED, {option name: dest}) or (ARGPARSE, {})
    accepted: dict[str, tuple[str, dict[str, str]]] = field(default_factory=dict)

    def hold(self, actions: Iterable[argparse.Action], owner: str = "the command") -> None:
        for action in actions:
            for flag in action.option_strings:
                self.taken_flags[flag] = owner
            self.taken_dests.add(action.dest)

    def _clash(self, flags: Sequence[str]) -> str | None:
        for flag in flags:
            if flag in self.taken_flags:
                return f"its option {flag} is already {self.taken_flags[flag]}'s"
        return None

    def add_typed(
        self, plugin: TransportPlugin, options: Sequence[PluginOption], target: Callable[[], argparse._ActionsContainer]
    ) -> bool:
        """Add ``options`` of ``plugin`` to the container ``target()`` makes (called only if they fit)."""
        flags = [option.flag_for(plugin.name) for option in options]
        names = [option.name for option in options]
        problem = self._clash(flags)
        if problem is None and len(set(flags)) != len(flags):
            problem = f"it declares one flag twice: {', '.join(sorted(f for f in flags if flags.count(f) > 1))}"
        if problem is None and len(set(names)) != len(names):
            problem = "it declares one option name twice"
        if problem is None:
            problem = self._try(lambda p: self._add_options(p, plugin.name, options, flags, record=False))
        if problem is not None:
            warn(f"transport plugin {plugin.name!r} left out: {problem}")
            return False
        self._add_options(target(), plugin.name, options, flags, record=True)
        for flag in flags:
            self.taken_flags[flag] = plugin.name
        self.accepted[plugin.name] = (TYPED, {o.name: _dest(plugin.name, o.name) for o in options})
        return True

    def _add_options(
        self,
        container: argparse._ActionsContainer,
        plugin: str,
        options: Sequence[PluginOption],
        flags: Sequence[str],
        record: bool,
    ) -> None:
        for option, flag in zip(options, flags, strict=True):
            aliases = [a for a in option.aliases if a not in self.taken_flags and a not in flags]
            container.add_argument(flag, *aliases, **_argparse_kwargs(option, plugin))
            if record:
                for alias in aliases:
                    self.taken_flags[alias] = plugin

    def add_argparse(
        self,
        plugin: TransportPlugin,
        hook: Callable[[argparse.ArgumentParser], None],
        target: Callable[[], argparse._ActionsContainer],
    ) -> bool:
        """The deprecated hook: tried on a scratch parser first, added for real only if nothing clashes."""
        scratch = _Recorder()
        problem = self._try(lambda _: hook(scratch))
        if problem is None:
            problem = self._clash([f for a in scratch.recorded for f in a.option_strings])
        if problem is None:
            shared = sorted({a.dest for a in scratch.recorded} & self.taken_dests)
            if shared:
                problem = f"it would overwrite the value(s) {', '.join(shared)}"
        if problem is None:
            problem = self._try(lambda _: hook(target()))  # type: ignore[arg-type]
        if problem is not None:
            warn(f"transport plugin {plugin.name!r} left out: {problem}")
            return False
        self.hold(scratch.recorded, plugin.name)
        self.accepted[plugin.name] = (ARGPARSE, {})
        return True

    @staticmethod
    def _try(add: Callable[[argparse.ArgumentParser], object]) -> str | None:
        scratch = argparse.ArgumentParser(add_help=False)
        try:
            add(scratch)
        except Exception as exc:  # a plugin's declaration: any failure leaves it out, never the others
            return f"its options cannot be declared ({type(exc).__name__}: {exc})"
        return None

    def given(self, args: argparse.Namespace, plugin: str) -> dict[str, object]:
        """The options of ``plugin`` given on the command line, by option name."""
        _, dests = self.accepted.get(plugin, (TYPED, {}))
        return {name: getattr(args, dest) for name, dest in dests.items() if hasattr(args, dest)}


def declared(plugin: TransportPlugin, attribute: str) -> tuple[PluginOption, ...]:
    """``plugin.simulator_options`` / ``decoder_options``, checked to be PluginOption objects."""
    options = tuple(getattr(plugin, attribute))
    for option in options:
        if not isinstance(option, PluginOption):
            raise TypeError(f"{attribute} holds {option!r}, not a PluginOption")
    return options
