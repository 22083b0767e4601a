"""``starterbus __complete``: the words a shell may complete, for the scripts of ``starterbus completion``.

Hidden (not a command of the parser: ``main`` hands it over before parsing). It reads the command's options from
the real parser and offers, beside options and fixed choices: installed models (``--model``, ``params MODEL``),
the fleet's device names (``URL|NAME``, ``--device``; the fleet of ``--fleet FILE``, ``$STARTERBUS_FLEET`` or
the config file) and the keys of the model (``--model``, else the named device's model: ``read``/``watch`` KEY,
``write`` KEY=, ``crosscheck --keys``). It opens no device and prints nothing on any error: a completion never
fails loudly. The line ``:files`` asks the shell to offer file names too; no words at all means "file names".
"""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field

FILES = ":files"


@dataclass
class _Seen:
    """What the words before the one being completed said: option values by dest, positionals by metavar."""

    parser: argparse.ArgumentParser
    options: dict[str, str] = field(default_factory=dict)
    positionals: dict[str, str] = field(default_factory=dict)
    pending: argparse.Action | None = None  # an option whose value comes next
    next_positional: argparse.Action | None = None


def _takes_value(action: argparse.Action) -> bool:
    return action.nargs != 0


def _walk(parser: argparse.ArgumentParser, words: Sequence[str]) -> _Seen:
    seen = _Seen(parser)
    by_option = {o: a for a in parser._actions for o in a.option_strings}
    positionals = [a for a in parser._actions if not a.option_strings]
    place = 0
    for i, word in enumerate(words):
        pending = seen.pending
        if pending is not None and not (pending.nargs in ("*", "+") and word.startswith("-")):
            seen.options[pending.dest] = word
            if pending.nargs not in ("*", "+"):
                seen.pending = None
            continue
        seen.pending = None
        if word.startswith("-") and word != "-":
            name, eq, value = word.partition("=")
            action = by_option.get(name)
            if action is not None and _takes_value(action):
                if eq:
                    seen.options[action.dest] = value
                else:
                    seen.pending = action
            continue
        if place >= len(positionals):
            continue
        action = positionals[place]
        if isinstance(action, argparse._SubParsersAction):
            sub = action.choices.get(word)
            return _walk(sub, words[i + 1 :]) if sub is not None else seen
        seen.positionals.setdefault(str(action.metavar or action.dest), word)
        if action.nargs not in ("*", "+"):
            place += 1
    seen.next_positional = positionals[place] if place < len(positionals) else None
    return seen


def _models() -> list[str]:
    from starterbus.core.registry import profiles

    return profiles.names()


def _fleet_devices(seen: _Seen) -> dict[str, str]:
    """Device name -> model of the fleet file the command line would use (none configured: nothing)."""
    from starterbus.cli.target import default_fleet
    from starterbus.fleet.config import load_fleet

    path = default_fleet(seen.options.get("fleet"))
    if path is None:
        return {}
    return {d.name: d.model for d in load_fleet(path).devices}


def _keys(seen: _Seen, *, writable: bool = False) -> list[str]:
    """The point keys of the model the command line names (--model, else the device's); writable parameters."""
    from starterbus.core.registry import get_profile

    model = seen.options.get("model")
    if model is None:
        name = seen.positionals.get("URL|NAME", "")
        model = None if "://" in name else _fleet_devices(seen).get(name)
    if model is None:
        return []
    points = get_profile(model).points.values()
    return [p.key for p in points if p.writable] if writable else [p.key for p in points]


def _values(action: argparse.Action, seen: _Seen, current: str) -> list[str]:
    """The words that may fill ``action`` (an option's value or a positional), the current word given."""
    if action.choices is not None and not isinstance(action.choices, dict):
        return [str(c) for c in action.choices]
    if isinstance(action, argparse._SubParsersAction):
        return list(action.choices)
    metavar = str(action.metavar or "")
    if action.dest == "model" or metavar == "MODEL":  # a name, or a profile .toml
        return [m for m in _models() if m.startswith(current)] or [FILES]
    if action.dest == "device" or metavar == "URL|NAME":
        return list(_fleet_devices(seen))
    if action.dest in ("a", "b") and metavar in ("A", "B"):  # diff: a backup file, NAME, defaults[@MODEL]
        return [*_fleet_devices(seen), "defaults", *(f"defaults@{m}" for m in _models()), FILES]
    if metavar == "KEY=VALUE":
        return [f"{key}=" for key in _keys(seen, writable=True)]
    if metavar == "KEY":
        keys = _keys(seen)
        if action.option_strings and "," in current:  # --keys a,b,...: the last one
            head = current.rsplit(",", 1)[0] + ","
            return [head + key for key in keys]
        return keys
    return []


def candidates(words: Sequence[str]) -> list[str]:
    """The completions of the last of ``words`` (the words after ``starterbus``; the last may be empty)."""
    from starterbus.cli.completion import command_names, command_parser

    *before, current = list(words) or [""]
    if not before:
        return [w for w in (*command_names(), "--help", "--version") if w.startswith(current)]
    parser = command_parser(before[0])
    if parser is None:
        return []
    seen = _walk(parser, before[1:])
    if seen.pending is not None and not (seen.pending.nargs in ("*", "+") and current.startswith("-")):
        words_out = _values(seen.pending, seen, current)
    elif current.startswith("-"):
        name, eq, value = current.partition("=")
        option = {o: a for a in seen.parser._actions for o in a.option_strings}.get(name)
        if eq and option is not None and _takes_value(option):
            return [f"{name}={w}" for w in _values(option, seen, value) if w != FILES and w.startswith(value)]
        words_out = sorted({o for a in seen.parser._actions for o in a.option_strings if o.startswith("--")})
    elif seen.next_positional is not None:
        words_out = _values(seen.next_positional, seen, current)
    else:
        words_out = []
    return [w for w in words_out if w == FILES or w.startswith(current)]


def _bash_words(line: str) -> list[str]:
    """The words after ``starterbus`` of a bash COMP_LINE cut at the cursor (an open quote is closed)."""
    lexer = shlex.shlex(line, posix=True, punctuation_chars=False)
    lexer.whitespace_split = True
    lexer.commenters = ""
    words: list[str] = []
    try:
        words.extend(lexer)
    except ValueError:  # an unterminated quote: the word being typed
        words.append(lexer.token)
    if not line or line[-1].isspace():
        words.append("")
    return words[1:]


def complete_main(argv: Sequence[str]) -> int:
    """``__complete WORD...`` (the words after ``starterbus``, the last being completed) or ``__complete --bash
    LINE CUR`` (COMP_LINE up to the cursor and bash's own current word, which ends at ``=`` or ``:``, so that each
    word printed replaces just that)."""
    args = list(argv)
    trim: str | None = None
    if args[:1] == ["--bash"] and len(args) in (2, 3):
        words, trim = _bash_words(args[1]), (args[2] if len(args) == 3 else "")
    else:
        words = args[1:] if args[:1] == ["--"] else args
    try:
        found = candidates(words)
    except Exception:  # a completion never fails loudly: a bad fleet file or model simply offers nothing
        return 0
    typed = words[-1] if words else ""
    for word in found:
        trimmed = trim is not None and word != FILES and typed.endswith(trim) and word.startswith(typed)
        sys.stdout.write((word[len(typed) - len(trim or "") :] if trimmed else word) + "\n")
    return 0
