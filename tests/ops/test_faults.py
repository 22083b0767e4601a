"""The device's own fault history reads with the profile's fault table: in reads, backups and history rows."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.core.fault_codes import fault_text, is_fault_code, value_text
from starterbus.core.model import Value
from starterbus.core.registry import get_profile

from .conftest import Line


def test_fault_code_points_are_recognised() -> None:
    j8 = get_profile("jjr8000")
    assert is_fault_code(j8, j8.points["last_fault_code"]) and is_fault_code(j8, j8.points["fault_2_code"])
    assert not is_fault_code(j8, j8.points["last_fault_current"])
    assert not is_fault_code(j8, j8.points["status_word"])
    assert value_text(j8, Value.from_raw(j8.points["fault_3_code"], 6)) == "6: motor overload"
    assert fault_text(j8, 0) == "0: no fault recorded"
    assert fault_text(j8, 14) == "14: unknown fault 14"  # a blank row of the manual's table
    assert fault_text(get_profile("jjr5000"), 5) == "5: mains phase loss"  # the JJR5000 manual's own code 5


@pytest.fixture
def tripped(line: Line) -> Line:
    """Unit 5 (a JJR8000) tripped on fault 6 and was reset: its fault history holds 6, then zeros."""
    line.starters[5].inject_fault(6)
    line.starters[5].fault_reset()
    return line


def test_read_and_backup_decode_the_fault_history(
    tripped: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line = tripped
    assert main(["read", line.url(5), "--model", "jjr8000", "last_fault_code", "fault_2_code"]) == 0
    out = capsys.readouterr().out
    assert "6: motor overload" in out and "0: no fault recorded" in out
    assert main(["read", line.url(5), "--model", "jjr8000", "last_fault_code", "--json"]) == 0
    (value,) = json.loads(capsys.readouterr().out)["values"]
    assert (value["raw"], value["text"]) == (6, "6: motor overload")
    assert main(["backup", line.url(5), "--model", "jjr8000", "-o", str(tmp_path / "j8.toml")]) == 0
    assert 'last_fault_code = "6: motor overload"' in (tmp_path / "j8.toml").read_text(encoding="utf-8")


def test_poll_and_watch_tables_decode_fault_code_points(
    tripped: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line = tripped
    plant = tmp_path / "plant.toml"
    plant.write_text(
        f'[[bus]]\nname = "l1"\nurl = "modbus-rtu://{line.port}?timeout=0.3"\n'
        'device = [{ name = "mill", model = "jjr8000", address = 5, measurements = ["last_fault_code"] }]\n',
        encoding="utf-8",
    )
    assert main(["poll", str(plant), "--once"]) == 0
    (row,) = [r for r in capsys.readouterr().out.splitlines() if r.startswith("mill ")]
    assert "last_fault_code 6: motor overload" in row
    assert main(["watch", "mill", "--fleet", str(plant), "last_fault_code", "fault_2_code", "--once"]) == 0
    out = capsys.readouterr().out
    assert "6: motor overload" in out and "0: no fault recorded" in out
