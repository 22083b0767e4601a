"""A URL whose settings the model cannot speak fails fleet load, ``validate`` and opening alike, naming the key,
the value and the allowed values (issue 26, item 6). The allowed values are the profile's (the manuals' ranges)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.core.device import open_device
from starterbus.core.errors import ConfigurationError
from starterbus.fleet.config import parse_fleet

# (bus URL, model, device address, device options, what the error must say: key, value, allowed values)
REFUSED = [
    # Modbus RTU: baud rates of the model (JJR5000/SSD1 2400-19200, JJR8000 1200-19200), parity, stop bits, unit
    ("modbus-rtu:///dev/null?baudrate=115200", "jjr5000", 2, {}, r"baudrate: .*2400, 4800, 9600, 19200 .*115200"),
    ("modbus-rtu:///dev/null?baudrate=1200", "ssd1", 2, {}, r"baudrate: .*2400, 4800, 9600, 19200 .*not 1200"),
    ("modbus-rtu:///dev/null?baudrate=600", "jjr8000", 2, {}, r"baudrate: .*1200, 2400, 4800, 9600, 19200 .*600"),
    ("modbus-rtu:///dev/null?parity=M", "jjr5000", 2, {}, r"parity: 'M' is not N, E or O"),
    ("modbus-rtu:///dev/null", "jjr5000", 2, {"stopbits": 3}, r"stopbits: 3 is outside 1\.\.2"),
    ("modbus-rtu:///dev/null", "ssd1", 246, {}, r"unit: 246 is not a SSD1 slave address.* 1\.\.245"),
    ("modbus-rtu:///dev/null", "jjr5000", 248, {}, r"unit: 248 is outside 0\.\.247"),
    # Profibus: the PPO types and DP stations of the model
    ("profibus-pkw+sim://?ppo=2", "jjr5000", None, {}, r"ppo: 2 is not 1 \(PPO1.*or 3 \(PPO3"),
    ("profibus-pkw+sim://?ppo=1", "jjr8000", 0, {}, r"station: 0 is outside JJR8000's range 1\.\.127"),
    ("profibus-pkw+sim://?ppo=1", "jjr5000", 127, {}, r"station: 127 .*range 0\.\.126"),
    # DeviceNet (JJR8000): MAC IDs 1-63, bit rates 125/250/500 k
    ("devicenet://virtual/bus0", "jjr8000", 64, {}, r"mac: 64 is outside 1\.\.63"),
    ("devicenet://virtual/bus0?bitrate=100000", "jjr8000", 5, {}, r"bitrate.* 100000 .*125000, 250000, 500000"),
]


def _fleet(url: str, model: str, address: int | None, options: dict[str, object]) -> str:
    device = f'[[bus.device]]\nname = "d"\nmodel = "{model}"\n'
    if address is not None:
        device += f"address = {address}\n"
    if options:
        device += "options = { " + ", ".join(f"{k} = {json.dumps(v)}" for k, v in options.items()) + " }\n"
    return f'[[bus]]\nname = "line"\nurl = "{url}"\n{device}'


@pytest.mark.parametrize(("url", "model", "address", "options", "said"), REFUSED)
def test_fleet_load_and_opening_refuse_what_the_model_cannot_speak(
    url: str, model: str, address: int | None, options: dict[str, object], said: str
) -> None:
    with pytest.raises(ConfigurationError, match=said) as refused:
        parse_fleet(_fleet(url, model, address, options), "plant.toml")
    assert str(refused.value).startswith("plant.toml: line 4: bus[0].device[0]: "), "file, line and device named"
    device_url = re.search(r"device\[0\]: (\S+?): ", str(refused.value))
    assert device_url is not None
    with pytest.raises(ConfigurationError, match=said):  # opening the device the same URL: the same refusal
        open_device(device_url.group(1), model)


@pytest.mark.parametrize(
    ("url", "model", "address", "options"),
    [
        ("modbus-rtu:///dev/null?baudrate=19200&parity=E&stopbits=2", "jjr5000", 247, {}),
        ("modbus-rtu:///dev/null?baudrate=1200", "jjr8000", 1, {}),
        ("modbus-rtu:///dev/null", "ssd1", 0, {}),  # 0: broadcast
        ("profibus-pkw+sim://?ppo=3", "jjr5000", 126, {}),
        ("devicenet://virtual/bus0?bitrate=125000", "jjr8000", 63, {}),
    ],
)
def test_what_the_model_speaks_loads(url: str, model: str, address: int | None, options: dict[str, object]) -> None:
    """The limits themselves are accepted (so the refusals above are the model's ranges, not any value)."""
    assert [d.name for d in parse_fleet(_fleet(url, model, address, options)).devices] == ["d"]


def test_validate_refuses_115200_baud_on_a_jjr5000_naming_the_allowed_rates(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The issue's case: this fleet file passed `validate`, then polled as online samples carrying the error."""
    path = tmp_path / "plant.toml"
    path.write_text(_fleet("modbus-rtu:///dev/ttyUSB0?baudrate=115200&parity=E", "jjr5000", 2, {}))
    assert main(["validate", str(path)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert re.search(r"plant\.toml: line 4: .*baudrate: JJR5000 speaks 2400, 4800, 9600, 19200 baud, not 115200", err)
    assert main(["validate", str(path), "--json"]) == 1
    [result] = json.loads(capsys.readouterr().out)
    assert result["valid"] is False and "115200" in result["error"] and "19200" in result["error"]
