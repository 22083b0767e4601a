"""``starterbus scan modbus-tcp://HOST:PORT`` finds the units behind a simulated gateway and tells their models
as the RTU scan does; the gateway's 0x0B (target failed to respond), 0x0A (path unavailable) and silence are
nobody there. The fleet file it writes validates and polls."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.transports.modbus.master.mbap import encode_adu
from starterbus.transports.modbus.simulator.tcp import ModbusTcpSimulator


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def test_scan_finds_the_units_behind_a_gateway(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    starters = {
        2: SimulatedStarter(get_profile("jjr5000"), values={"slave_address": 2}),
        3: SimulatedStarter(get_profile("ssd1"), values={"slave_address": 3}),
        5: SimulatedStarter(get_profile("jjr8000"), values={"slave_address": 5}),
    }
    asked: set[int] = set()

    def gateway(transaction: int, unit: int, pdu: bytes) -> bytes | None:
        asked.add(unit)
        if unit == 4:
            return encode_adu(transaction, unit, bytes((pdu[0] | 0x80, 0x0A)))  # path unavailable
        return b"" if unit == 6 else None  # 6: silence; others: as served (0x0B for an absent unit)

    fleet = tmp_path / "gw.toml"
    with ModbusTcpSimulator(starters) as sim:
        sim.answer_hook = gateway
        url = f"modbus-tcp://{sim.where}"
        code, out, err = run(capsys, "scan", url, "--units", "1-7", "--timeout", "0.2", "-o", str(fleet), "--json")
        assert code == 0, err
        found = json.loads(out)["found"]
        assert [(f["unit"], f["model"]) for f in found] == [(2, "jjr5000"), (3, "ssd1"), (5, "jjr8000")]
        assert asked == set(range(1, 8)) and "unit 5: jjr8000" in err
        assert sim.connections == 1  # one connection to the gateway for the whole scan
        text = fleet.read_text(encoding="utf-8")
        assert f'url = "{url}"' in text and "address = 5" in text
        assert run(capsys, "validate", str(fleet))[0] == 0
        code, out, err = run(capsys, "poll", str(fleet), "--once", "--json")
        assert code == 0, err
        samples = [json.loads(line) for line in out.splitlines()]
        assert sorted((s["device"], s["online"]) for s in samples) == [
            ("jjr5000-2", True), ("jjr8000-5", True), ("ssd1-3", True),
        ]  # fmt: skip


def test_nobody_behind_the_gateway(capsys: pytest.CaptureFixture[str]) -> None:
    with ModbusTcpSimulator({9: SimulatedStarter(get_profile("ssd1"))}) as sim:  # units 1-3: the gateway's 0x0B
        code, _, err = run(capsys, "scan", f"modbus-tcp://{sim.where}", "--units", "1-3", "--timeout", "0.2")
        assert code == 1 and "no unit answered" in err
        code, _, err = run(capsys, "scan", f"modbus-tcp://{sim.where}", "--baudrates", "9600")
        assert code == 1 and "gateway's settings" in err
