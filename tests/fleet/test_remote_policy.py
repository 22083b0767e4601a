"""The fleet file's ``remote`` table: what remote callers may do to a device, nothing unless listed."""

from __future__ import annotations

import pytest

from starterbus.core.errors import ConfigurationError
from starterbus.core.status import Command
from starterbus.fleet.config import parse_fleet

BASE = """
[[bus]]
name = "l1"
url = "modbus-rtu:///dev/null?timeout=0.3"

  [[bus.device]]
  name = "conveyor"
  model = "jjr5000"
  address = 2
"""


def test_nothing_is_allowed_by_default() -> None:
    device = parse_fleet(BASE, "f.toml").devices[0]
    assert not any(device.remote.allows_command(c) for c in Command)
    assert not device.remote.allows_write("current_limit")


def test_listed_commands_and_parameters_are_allowed() -> None:
    text = BASE + '  remote = { commands = ["start", "reset"], write = ["0x0103", "ramp_time"] }\n'
    device = parse_fleet(text, "f.toml").devices[0]
    assert device.remote.allows_command(Command.START) and device.remote.allows_command(Command.FAULT_RESET)
    assert not device.remote.allows_command(Command.SOFT_STOP)
    assert device.remote.allows_write("current_limit") and device.remote.allows_write("ramp_time")


@pytest.mark.parametrize(
    ("remote", "message"),
    [
        ('remote = ["start"]', "must be a table"),
        ('remote = { commands = ["jump"] }', "must be a list of: start, stop, reset"),
        ('remote = { write = ["warp"] }', "no parameter or measurement 'warp'"),
        ('remote = { write = ["phase_a_current"] }', "not a writable parameter"),
        ("remote = { everything = true }", "unknown setting"),
    ],
)
def test_bad_remote_tables_name_the_key(remote: str, message: str) -> None:
    with pytest.raises(ConfigurationError, match=message) as info:
        parse_fleet(BASE + f"  {remote}\n", "f.toml")
    assert "f.toml" in str(info.value) and "remote" in str(info.value)
