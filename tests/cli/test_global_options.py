"""Global options go before the command (`starterbus -v opcua --demo`): the command's own options are still
built, whatever global options come first."""

from __future__ import annotations

import pytest

from starterbus.cli.parser import parse_arguments


@pytest.mark.parametrize("globals_", [[], ["-v"], ["-vv"], ["--verbose", "-v"]])
def test_a_commands_options_after_global_options(globals_: list[str]) -> None:
    args = parse_arguments([*globals_, "opcua", "--demo", "--pki", "here"])
    assert (args.command_name, args.demo, args.pki) == ("opcua", True, "here")
    assert args.log_level == sum(g.count("v") if g.startswith("-v") else 1 for g in globals_)
    assert parse_arguments([*globals_, "serve", "--demo", "--http", "127.0.0.1:0"]).http == "127.0.0.1:0"
    assert parse_arguments([*globals_, "poll", "fleet.toml", "--once"]).once
