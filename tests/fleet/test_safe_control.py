"""Writes and commands from the CLI: confirmation, --yes, --dry-run, the audit log and the read-back check.

Everything runs against the Modbus RTU simulator on a real pseudo-terminal.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.core.model import PointDef
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter


class StickyStarter(SimulatedStarter):
    """A faulty device: acknowledges every write of current_limit but keeps the old value."""

    def write(self, point: PointDef, raw: int) -> None:
        if point.key != "current_limit":
            super().write(point, raw)


@pytest.fixture
def line() -> Iterator[tuple[dict[int, str], dict[int, SimulatedStarter]]]:
    from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

    profile = get_profile("jjr5000")
    starters: dict[int, SimulatedStarter] = {2: SimulatedStarter(profile), 3: StickyStarter(profile)}
    sim = ModbusRtuSimulator(starters, pty=True).start()
    try:
        yield sim.client_urls(), starters
    finally:
        sim.close()


def test_write_is_audited_and_read_back(
    line: tuple[dict[int, str], dict[int, SimulatedStarter]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    urls, starters = line
    log = tmp_path / "audit.jsonl"
    old = starters[2].params["current_limit"]
    code = main(
        ["write", urls[2], "--model", "jjr5000", "current_limit=380", "--yes", "--audit-log", str(log), "--json"]
    )
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["written"][0]["read_back"] == "380 %"
    assert starters[2].params["current_limit"] == 380
    entries = [json.loads(x) for x in log.read_text(encoding="utf-8").splitlines()]
    assert len(entries) == 1
    entry = entries[0]
    assert entry["action"] == "write" and entry["key"] == "current_limit"
    assert (entry["old"], entry["new"], entry["result"]) == (f"{old} %", "380 %", "ok")
    assert entry["device"] == urls[2] and entry["time"]


def test_read_back_mismatch_is_an_error(
    line: tuple[dict[int, str], dict[int, SimulatedStarter]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    urls, _ = line
    log = tmp_path / "audit.jsonl"
    code = main(["write", urls[3], "--model", "jjr5000", "current_limit=400", "--yes", "--audit-log", str(log)])
    assert code == 1
    err = capsys.readouterr().err
    assert "wrote 400 % but read back 350 %" in err
    entry = json.loads(log.read_text(encoding="utf-8").splitlines()[-1])
    assert (entry["result"], entry["new"], entry["read_back"]) == ("mismatch", "400 %", "350 %")


def test_without_terminal_and_without_yes_nothing_is_sent(
    line: tuple[dict[int, str], dict[int, SimulatedStarter]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    urls, starters = line
    log = tmp_path / "audit.jsonl"
    before = dict(starters[2].params)
    assert main(["write", urls[2], "--model", "jjr5000", "ramp_time=30", "--audit-log", str(log)]) == 1
    assert "refused without --yes" in capsys.readouterr().err
    assert main(["start", urls[2], "--model", "jjr5000", "--audit-log", str(log)]) == 1
    assert "refused without --yes" in capsys.readouterr().err
    assert starters[2].params == before
    assert starters[2].phase.value == "stopped"
    assert not log.exists()


def test_dry_run_shows_frames_and_sends_nothing(
    line: tuple[dict[int, str], dict[int, SimulatedStarter]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    urls, starters = line
    log = tmp_path / "audit.jsonl"
    before = dict(starters[2].params)
    assert (
        main(["write", urls[2], "--model", "jjr5000", "current_limit=380", "--dry-run", "--audit-log", str(log)]) == 0
    )
    out = capsys.readouterr().out
    assert "02 06 01 03 01 7C 78 74" in out.upper()  # the manual's own frame, CRC included
    assert main(["start", urls[2], "--model", "jjr5000", "--dry-run", "--json"]) == 0
    frames = json.loads(capsys.readouterr().out)["would_send"][0]["frames"]
    assert any("02 06 00 00 00 09" in f.upper() for f in frames)
    assert starters[2].params == before and starters[2].phase.value == "stopped"
    assert not log.exists()


def test_out_of_range_write_is_refused_before_confirmation(
    line: tuple[dict[int, str], dict[int, SimulatedStarter]], capsys: pytest.CaptureFixture[str]
) -> None:
    urls, _ = line
    assert main(["write", urls[2], "--model", "jjr5000", "current_limit=149", "--yes"]) == 1
    assert "149 % is out of range 150..500 %" in capsys.readouterr().err


def test_command_is_audited(
    line: tuple[dict[int, str], dict[int, SimulatedStarter]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    urls, starters = line
    log = tmp_path / "audit.jsonl"
    assert main(["start", urls[2], "--model", "jjr5000", "--yes", "--audit-log", str(log)]) == 0
    assert starters[2].phase.value == "starting"
    assert main(["stop", urls[2], "--model", "jjr5000", "--yes", "--audit-log", str(log)]) == 0
    entries = [json.loads(x) for x in log.read_text(encoding="utf-8").splitlines()]
    assert [(e["command"], e["result"]) for e in entries] == [("start", "ok"), ("stop", "ok")]
    capsys.readouterr()
