"""backup, diff, restore, record, history and plot take the device names of a fleet file (`--fleet`, or
$STARTERBUS_FLEET), resolved as every other command resolves them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.fleet.config import load_fleet

from .conftest import Line


@pytest.fixture
def plant(line: Line, tmp_path: Path) -> Path:
    path = tmp_path / "plant.toml"
    path.write_text(
        f"""[[bus]]
name = "mcc-1"
url = "modbus-rtu://{line.port}?timeout=0.3"
device = [
  {{ name = "conveyor-a", model = "jjr5000", address = 2 }},
  {{ name = "conveyor-b", model = "jjr5000", address = 3 }},
]
""",
        encoding="utf-8",
    )
    return path


def test_backup_diff_restore_by_name(
    line: Line, plant: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    saved = tmp_path / "a.toml"
    assert main(["backup", "conveyor-a", "--fleet", str(plant), "-o", str(saved), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["model"] == "jjr5000"
    monkeypatch.setenv("STARTERBUS_FLEET", str(plant))
    assert main(["diff", "conveyor-a", "conveyor-b", "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert (report["a"], report["b"]) == ("conveyor-a", "conveyor-b")
    assert {row["key"] for row in report["differences"]} >= {"current_limit", "ramp_time"}
    assert main(["restore", str(saved), "conveyor-b", "--yes", "--json"]) == 0
    capsys.readouterr()
    assert line.starters[3].params["ramp_time"] == line.starters[2].params["ramp_time"]
    assert main(["diff", str(saved), "conveyor-b"]) == 0
    assert "equal" in capsys.readouterr().out
    assert main(["diff", "pump-9", str(saved)]) == 2
    assert "no device named 'pump-9'" in capsys.readouterr().err
    monkeypatch.delenv("STARTERBUS_FLEET")
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))
    assert main(["diff", "conveyor-a", str(saved)]) == 2
    assert "--fleet FILE" in capsys.readouterr().err


def test_record_history_plot_by_name(
    line: Line, plant: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "rec"
    fleet = ["--fleet", str(plant)]
    code = main(["record", "conveyor-a", *fleet, "--start", "--yes", "--settle", "0.1", "-o", str(out), "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert code == 0 and summary["device"] == "conveyor-a"  # recorded under its name, as `poll --record` does
    db = summary["files"]["db"]
    assert main(["history", db, "--device", "conveyor-a", "--events", "--json"]) == 0
    (start,) = json.loads(capsys.readouterr().out)["events"]
    url = load_fleet(plant).devices_by_name["conveyor-a"].url
    assert main(["history", db, "--device", url, *fleet, "--events", "--json"]) == 0  # its URL finds its name
    assert json.loads(capsys.readouterr().out)["events"] == [start]
    assert main(["history", db, "--device", "conveyor-b"]) == 1
    assert "nothing recorded of 'conveyor-b' (devices: conveyor-a)" in capsys.readouterr().err
    png = tmp_path / "start.png"
    assert main(["plot", db, "--device", url, *fleet, "--event", str(start["id"]), "-o", str(png)]) == 0
    assert "samples of conveyor-a" in capsys.readouterr().out and png.stat().st_size > 0
