"""`record --start` checks everything before the start command, and after it keeps what it can and says the
motor runs: a missing matplotlib, an output that cannot be written, a motor already going, a starter on keypad
control, each one line with nothing sent to the (counting) simulated starter; a disk or line error after the
start, the samples saved where possible and the way to stop the motor printed.
"""

from __future__ import annotations

import errno
import json
import os
import re
import sys
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.core.device import Device
from starterbus.core.errors import TimeoutError
from starterbus.core.simulator import Phase
from starterbus.ops import record
from starterbus.ops.history import HistoryStore
from starterbus.ops.recording import Recording

from .conftest import Line

WRITE = 6  # Modbus FC06: the control word (and every parameter write) of this line


def record_args(line: Line, out: Path, *extra: str) -> list[str]:
    return ["record", line.url(2), "--model", "jjr5000", "--start", "--yes", "-o", str(out), *extra]


def no_matplotlib(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ("matplotlib", "matplotlib.figure", "matplotlib.patches"):
        monkeypatch.setitem(sys.modules, name, None)  # `import` now raises ImportError


def nothing_sent(line: Line) -> None:
    starter = line.starters[2]
    assert WRITE not in line.functions
    assert starter.control_writes == [] and starter.control_word == 0 and starter.phase is Phase.STOPPED


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


def test_without_matplotlib_record_and_plot_say_which_extra_and_send_nothing(
    line: Line, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    no_matplotlib(monkeypatch)
    out = tmp_path / "rec"
    assert main(record_args(line, out)) == 1
    err = one_line(capsys.readouterr().err)
    assert 'pip install "starterbus[plot]"' in err and "--no-plot" in err
    nothing_sent(line)
    assert not out.exists()  # checked before anything else
    assert main(["plot", str(tmp_path / "h.db"), "--device", "m1", "--event", "1"]) == 1
    assert 'pip install "starterbus[plot]"' in one_line(capsys.readouterr().err)


def test_no_plot_records_without_matplotlib(
    line: Line, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    no_matplotlib(monkeypatch)
    assert main([*record_args(line, tmp_path, "--no-plot"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert set(summary["files"]) == {"csv", "db"} and summary["not_saved"] == {}
    assert summary["ended"] == "running"


def test_an_output_that_cannot_be_written_is_refused_before_the_start(
    line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a_file = tmp_path / "file"
    a_file.write_text("x", encoding="utf-8")
    assert main(record_args(line, a_file)) == 1
    assert "exists and is not a directory" in one_line(capsys.readouterr().err)
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "starts.db").write_text("not a database", encoding="utf-8")
    assert main(record_args(line, foreign)) == 1
    assert "starts.db: not a starterbus history database" in one_line(capsys.readouterr().err)
    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        assert main(record_args(line, locked)) == 1
        assert "cannot write there" in one_line(capsys.readouterr().err)
    nothing_sent(line)


def test_a_motor_already_going_or_on_keypad_control_is_not_started(
    line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    starter = line.starters[2]
    starter.params["control_source"] = 1  # keypad
    assert main(record_args(line, tmp_path)) == 1
    assert "controlled from elsewhere: its control_source (0x013E) is keypad" in one_line(capsys.readouterr().err)
    nothing_sent(line)
    starter.params["control_source"] = 4  # bus
    starter.start("keypad")
    assert main(record_args(line, tmp_path)) == 1
    # starting, or running once its ramp has passed (the starter runs on the real clock)
    assert re.search(r"is already (starting|running): there is no start to record", one_line(capsys.readouterr().err))
    assert WRITE not in line.functions and starter.control_writes == []


def test_a_disk_error_after_the_start_keeps_the_rest_and_says_the_motor_runs(
    line: Line, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def disk_full(*_: object, **__: object) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(record, "write_csv", disk_full)
    assert main([*record_args(line, tmp_path, "--no-plot"), "--json"]) == 1
    captured = capsys.readouterr()
    summary = json.loads(captured.out)  # stdout stays JSON
    assert "No space left on device" in summary["not_saved"]["csv"] and set(summary["files"]) == {"db"}
    with HistoryStore(summary["files"]["db"], create=False) as store:
        assert len(store.samples()) == summary["samples"] > 0
    assert "not saved:" in captured.err and "No space left" in captured.err
    assert f"is running (this command started it); stop it with: starterbus stop '{line.url(2)}' --model jjr5000" in (
        captured.err
    )
    assert line.starters[2].phase is Phase.RUNNING


def test_a_line_error_after_the_start_saves_what_was_sampled(
    line: Line, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    starter = line.starters[2]
    status = Device.status

    def fails_once_running(self: Device) -> object:
        if starter.phase is Phase.RUNNING:
            raise TimeoutError("no answer from unit 2")
        return status(self)

    monkeypatch.setattr(Device, "status", fails_once_running)
    assert main([*record_args(line, tmp_path, "--no-plot"), "--json"]) == 1
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert summary["ended"] == "sampling failed: no answer from unit 2" and summary["samples"] > 0
    rows = Path(summary["files"]["csv"]).read_text(encoding="utf-8").strip().splitlines()[1:]
    assert len(rows) == summary["samples"]
    # the phase is looked at before the status is read: the read may already see the motor running, once
    assert sum("starting" in row for row in rows) >= len(rows) - 1
    assert "stop it with: starterbus stop" in captured.err


def test_record_never_overwrites_a_recording(line: Line, tmp_path: Path) -> None:
    rec = Recording("m1", "jjr5000", started=1_800_000_000.0)
    first = record.write_all(rec, tmp_path, plot=False)
    second = record.write_all(rec, tmp_path, plot=False)  # the same second: another name
    assert first.files["csv"].name == "start-20270115-080000.csv"
    assert second.files["csv"].name == "start-20270115-080000-2.csv" and not second.errors
