"""Argument order of the device commands: options may sit between the URL and the keys."""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest

from starterbus.cli.main import main
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter


@pytest.fixture(scope="module")
def url() -> Iterator[str]:
    from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

    sim = ModbusRtuSimulator({2: SimulatedStarter(get_profile("jjr5000"))}, pty=True).start()
    try:
        yield sim.client_urls()[2]
    finally:
        sim.close()


@pytest.mark.parametrize(
    "order",
    [
        ["read", "{url}", "--model", "jjr5000", "0x0100", "current_limit"],
        ["read", "--model", "jjr5000", "{url}", "0x0100", "current_limit"],
        ["read", "{url}", "0x0100", "current_limit", "--model", "jjr5000"],
        ["read", "{url}", "--model", "jjr5000", "--json", "0x0100", "current_limit"],
    ],
)
def test_keys_after_options(url: str, order: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    argv = [a.format(url=url) for a in order]
    if "--json" not in argv:
        argv.append("--json")
    assert main(argv) == 0
    values = json.loads(capsys.readouterr().out)["values"]
    assert [v["key"] for v in values] == ["motor_rated_current", "current_limit"]
    assert values[0]["value"] == 390


def test_unknown_option_is_still_an_error(url: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["read", url, "--model", "jjr5000", "--bogus", "0x0100"])
    assert info.value.code == 2
    assert "unrecognized arguments: --bogus" in capsys.readouterr().err
