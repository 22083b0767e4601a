"""``read --raw`` and ``write --raw`` against the simulator: registers as they are, a write outside the model's
range goes through (that is the point) with confirmation and an audit record, and every refused or dry-run raw
write sends nothing (the simulator counts the requests it got)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from starterbus.cli.main import main
from starterbus.transports.modbus.codec.frames import AnyRequest, WriteRequest

if TYPE_CHECKING:
    from starterbus.tests.modbus.conftest import SimFactory


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def audit(path: Path) -> list[dict[str, object]]:
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()] if path.exists() else []


def test_read_raw_prints_registers_hex_and_decimal(make_sim: SimFactory, capsys: pytest.CaptureFixture[str]) -> None:
    sim = make_sim("ssd1")
    sim.starters[2].params["motor_rated_current"] = 390
    sim.starters[2].params["current_limit"] = 380
    code, out, err = run(capsys, "read", sim.url(2), "--model", "ssd1", "--raw", "0x0100:4")
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0].split() == ["address", "dec", "hex", "signed", "key"]
    assert lines[2].split() == ["0x0100", "390", "0x0186", "390", "motor_rated_current"]
    assert lines[5].split()[:3] == ["0x0103", "380", "0x017C"] and len(lines) == 6
    code, out, err = run(capsys, "read", sim.url(2), "--model", "ssd1", "--raw", "0x0103", "--json")
    assert code == 0, err
    assert json.loads(out)["registers"] == [
        {"address": "0x0103", "value": 380, "hex": "0x017C", "key": "current_limit"}
    ]


def test_write_raw_bypasses_the_range_with_confirmation_and_audit(
    make_sim: SimFactory, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    sim = make_sim("ssd1")
    log = tmp_path / "audit.jsonl"
    url = sim.url(2)
    code, _, err = run(capsys, "write", url, "--model", "ssd1", "current_limit=9000", "--yes", "--audit-log", str(log))
    assert code == 1 and "out of range" in err  # the model's write refuses it
    before = sim.counters.requests
    code, _, err = run(capsys, "write", url, "--model", "ssd1", "--raw", "0x0103=510", "--yes", "--audit-log", str(log))
    assert code == 1 and "bypasses the model" in err  # said loudly
    assert "error 0x03" in err.splitlines()[-1] and sim.counters.requests > before  # sent: the device refused it
    assert audit(log)[-1]["result"] == "failed"
    code, out, err = run(capsys, "write", url, "--model", "ssd1", "--raw", "0x0103=0x017C", "--yes", "--audit-log",
                         str(log), "--json")  # fmt: skip
    assert code == 0, err
    written = json.loads(out)["written"]  # stdout stays JSON
    assert written == [{"address": "0x0103", "key": "current_limit", "old": 350, "new": 380, "read_back": 380,
                        "result": "ok"}]  # fmt: skip
    assert sim.starters[2].params["current_limit"] == 380
    record = audit(log)[-1]
    assert record["action"] == "write-raw" and record["address"] == "0x0103" and record["result"] == "ok"


def test_refused_and_dry_run_raw_writes_send_nothing(
    make_sim: SimFactory, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    sim = make_sim("jjr8000")
    log = tmp_path / "audit.jsonl"
    url = sim.url(2)
    seen: list[AnyRequest] = []
    sim.fault_hook = seen.append  # records; None: answer as usual
    code, out, _ = run(capsys, "write", url, "--model", "jjr8000", "--raw", "0x0103=30", "--dry-run")
    assert code == 0 and "02 06 01 03 00 1E" in out and "nothing sent" in out
    code, _, err = run(capsys, "write", url, "--model", "jjr8000", "--raw", "0x0103=30", "--audit-log", str(log))
    assert code == 1 and "without --yes" in err and err.splitlines()[-1].count("\n") == 0
    code, _, err = run(capsys, "write", url, "--model", "jjr8000", "--raw", "0x0000=9", "--yes", "--audit-log",
                       str(log))  # fmt: skip
    assert code == 1 and "control word" in err and "start" in err
    code, _, err = run(capsys, "write", url, "--model", "jjr8000", "--raw", "0x0103", "--yes")
    assert code == 1 and "ADDRESS=VALUE" in err
    code, _, err = run(capsys, "write", url, "--model", "jjr8000", "--raw", "0x0103=70000", "--yes")
    assert code == 1 and "outside 0..65535" in err
    assert seen == []  # nothing reached the slave
    assert [str(r["result"]).split(":")[0] for r in audit(log)] == ["refused", "refused"]
    sim.starters[2].start()
    code, _, err = run(capsys, "write", url, "--model", "jjr8000", "--raw", "0x0103=30", "--yes", "--audit-log",
                       str(log))  # fmt: skip
    assert code == 1 and "ramp_time" in err and "stop the motor first" in err
    assert seen and not [r for r in seen if isinstance(r, WriteRequest)]  # the status was read; nothing written
    assert sim.starters[2].params["ramp_time"] == 12


def test_raw_access_is_refused_without_modbus_registers(capsys: pytest.CaptureFixture[str]) -> None:
    url = "devicenet://virtual/raw-test?mac=5"
    for argv in (["read", url, "--model", "jjr8000", "--raw", "0x0100:4"],
                 ["write", url, "--model", "jjr8000", "--raw", "0x0103=3", "--yes"]):  # fmt: skip
        code, _, err = run(capsys, *argv)
        assert code == 1 and err.count("\n") == 1, err
        assert "devicenet transport has no Modbus register address space" in err and "modbus-rtu" in err
