"""Fleet files are validated with errors that name the file, the line and the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from starterbus.core.errors import ConfigurationError
from starterbus.fleet.config import load_fleet, parse_fleet

EXAMPLE = Path(__file__).parents[2] / "examples" / "fleet.toml"

GOOD = """\
[poll]
period = 0.5

[[bus]]
name = "line"
url = "modbus-rtu:///dev/ttyS9?baudrate=19200"

  [[bus.device]]
  name = "a"
  model = "jjr5000"
  address = 2
  parameters = ["0x0103"]

  [[bus.device]]
  name = "b"
  model = "ssd1"
  address = 3
  period = 2
"""


def test_example_fleet_is_valid() -> None:
    fleet = load_fleet(EXAMPLE)
    assert [b.name for b in fleet.buses] == ["mcc-1", "dp-gateway", "dnet"]
    assert len(fleet.devices) == 5
    assert fleet.devices_by_name["pump-b"].url.endswith("mac=11")


def test_device_urls_and_defaults() -> None:
    fleet = parse_fleet(GOOD, "f.toml")
    a, b = fleet.devices
    assert a.url == "modbus-rtu:///dev/ttyS9?baudrate=19200&unit=2"
    assert a.parameters == ("current_limit",)
    assert a.measurements == ("phase_a_current", "phase_b_current", "phase_c_current")
    assert (a.period, b.period) == (0.5, 2.0)


@pytest.mark.parametrize(
    ("old", "new", "line", "where", "message"),
    [
        ('model = "ssd1"', 'model = "ssd9"', 16, "bus[0].device[1].model", "ssd9"),
        ("address = 3", "address = 2", 17, "bus[0].device[1].address", "used twice"),
        ('name = "b"', 'name = "a"', 15, "bus[0].device[1].name", "defined twice"),
        (
            'parameters = ["0x0103"]',
            'parameters = ["0x0001"]',
            12,
            "bus[0].device[0].parameters",
            "measurement",
        ),
        ('parameters = ["0x0103"]', 'parameters = ["warp"]', 12, "bus[0].device[0].parameters", "warp"),
        ("period = 2", "period = -1", 18, "bus[0].device[1].period", "positive"),
        ("period = 0.5", "period = 'x'", 2, "poll.period", "positive"),
        (
            'url = "modbus-rtu:///dev/ttyS9?baudrate=19200"',
            'url = "ttyS9"',
            6,
            "bus[0].url",
            "not a device URL",
        ),
        ("address = 3", "adress = 3", 17, "bus[0].device[1].adress", "unknown setting"),
    ],
)
def test_errors_name_line_and_key(old: str, new: str, line: int, where: str, message: str) -> None:
    assert old in GOOD
    with pytest.raises(ConfigurationError) as info:
        parse_fleet(GOOD.replace(old, new, 1), "f.toml")
    text = str(info.value)
    assert text.startswith(f"f.toml: line {line}: {where}: "), text
    assert message in text


def test_model_without_the_bus_transport() -> None:
    text = GOOD.replace('url = "modbus-rtu:///dev/ttyS9?baudrate=19200"', 'url = "devicenet://virtual/x"')
    with pytest.raises(ConfigurationError, match=r"line 10: bus\[0\].device\[0\].model: JJR5000 has no devicenet"):
        parse_fleet(text, "f.toml")


def test_no_bus_and_syntax_errors() -> None:
    with pytest.raises(ConfigurationError, match="at least one"):
        parse_fleet("[poll]\nperiod = 1\n", "f.toml")
    with pytest.raises(ConfigurationError, match=r"^f.toml: .*line 1"):
        parse_fleet("[[bus]\n", "f.toml")
