"""Every command's --help ends with examples, and every example parses with the real parser (so none can rot)."""

from __future__ import annotations

import argparse
import re
import shlex

import pytest

from starterbus.cli.examples import EXAMPLES
from starterbus.cli.parser import build_parser, parse_arguments
from starterbus.tests.cli.test_habits import run

SHELL_OPERATORS = {"|", "||", "&", "&&", ";", ">", ">>", "<", "2>"}


def subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(action.choices)


COMMANDS = sorted(subparsers(build_parser([])))


def starterbus_words(line: str) -> list[str]:
    """The words of the ``starterbus`` command in an example line: a `` # comment`` dropped (as bash does: a
    ``#`` inside a word such as a CAN frame ``42E#00`` is no comment), then split as a shell would, and cut
    at the pipe or redirection around it."""
    lex = shlex.shlex(re.sub(r"(^|\s)#.*$", "", line), posix=True, punctuation_chars=True)
    lex.whitespace_split, lex.commenters = True, ""
    words = list(lex)
    start = words.index("starterbus")
    end = next((i for i in range(start, len(words)) if words[i] in SHELL_OPERATORS), len(words))
    return words[start + 1 : end]


def example_lines(epilog: str) -> list[str]:
    _, found, examples = epilog.partition("Examples:\n")
    assert found, "no Examples: section"
    return [line.strip() for line in examples.splitlines() if line.strip()]


@pytest.mark.parametrize("name", COMMANDS)
def test_every_example_of_every_command_parses(name: str) -> None:
    command = subparsers(build_parser([name]))[name]  # its options are built only when it is asked for
    lines = example_lines(command.epilog or "")
    assert len(lines) >= 1
    for line in lines:
        words = starterbus_words(line)
        assert words[0] == name, line
        try:
            args = parse_arguments(words)
        except SystemExit as exc:  # argparse printed the usage and why
            pytest.fail(f"{line!r} does not parse (exit {exc.code})")
        assert args.command_name == name


def test_every_command_has_examples_and_only_commands_have_them() -> None:
    assert set(EXAMPLES) == set(COMMANDS)


def test_examples_show_in_help_as_written() -> None:
    result = run("diff", "--help")
    assert result.returncode == 0
    assert "Examples:\n  starterbus diff conveyor-1.toml conveyor-1 " in result.stdout
    assert "script lines: AT UNIT" in run("simulate", "--help").stdout  # the command's own notes stay


def test_the_word_splitter_follows_the_shell() -> None:
    assert starterbus_words("candump -L can0 | starterbus decode devicenet -  # stdin") == ["decode", "devicenet", "-"]
    assert starterbus_words("starterbus decode devicenet 42E#004B > out.txt") == ["decode", "devicenet", "42E#004B"]
    assert starterbus_words('starterbus write x start_mode="voltage ramp"') == ["write", "x", "start_mode=voltage ramp"]
