"""Backup, diff and restore against simulated starters: the issue's check, the order and the refusals."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.core.device import open_device
from starterbus.core.errors import ConfigurationError, UnsupportedOperationError, ValidationError
from starterbus.core.model import PointDef
from starterbus.core.registry import get_profile
from starterbus.ops import backup as backups
from starterbus.ops.diff import parse_spec

from .conftest import Line

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def audit(path: Path) -> list[dict[str, object]]:
    return [json.loads(x) for x in path.read_text(encoding="utf-8").splitlines()] if path.exists() else []


def test_backup_diff_restore_diff(
    line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str], _audit_log_in_tmp: Path
) -> None:
    file_a = tmp_path / "a.toml"
    assert main(["backup", line.url(2), "--model", "jjr5000", "-o", str(file_a)]) == 0
    data = tomllib.loads(file_a.read_text(encoding="utf-8"))
    assert data["model"] == "jjr5000" and data["transport"] == "modbus-rtu" and data["taken"]
    assert data["profile_sha256"] and data["profile_source"].endswith("jjr5000.toml")
    limit = data["parameters"]["current_limit"]
    assert (limit["value"], limit["raw"], limit["unit"], limit["label"]) == (350, 350, "%", "current limit")
    assert data["parameters"]["start_mode"]["value"] == "current limit"
    assert len(data["parameters"]) == len(get_profile("jjr5000").parameters)
    capsys.readouterr()

    b = f"{line.url(3)}@jjr5000"
    assert main(["diff", str(file_a), b]) == 1
    out = capsys.readouterr().out
    rows = {ln.split()[0]: ln for ln in out.splitlines()[2:] if ln and not ln.startswith("4 differ")}
    assert set(rows) == {"ramp_time", "current_limit", "start_mode", "parameter_modify"}
    assert "350 %" in rows["current_limit"] and "400 %" in rows["current_limit"]
    assert "4 differ" in out

    line.functions.clear()
    assert main(["restore", str(file_a), line.url(3), "--model", "jjr5000", "--yes", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    order = [(w["key"], w["new"], w["result"]) for w in report["written"]]
    assert order[0] == ("parameter_modify", "enabled (1)", "ok")  # the lock is lifted first
    assert {k for k, _, _ in order[1:]} == {"ramp_time", "current_limit", "start_mode"}
    assert all(r == "ok" for _, _, r in order)
    assert line.starters[3].params == line.starters[2].params
    assert [e["key"] for e in audit(_audit_log_in_tmp)] == [k for k, _, _ in order]

    assert main(["diff", str(file_a), b, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["equal"] is True
    assert main(["diff", "defaults", str(file_a), "--json"]) == 1  # A is at the profile's defaults, but for its
    differences = json.loads(capsys.readouterr().out)["differences"]  # commissioning for the bus
    assert [(d["key"], d["raw_a"], d["raw_b"]) for d in differences] == [("control_source", 0, 4)]


def test_restore_puts_the_lock_back_last(line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    file_b = tmp_path / "b.toml"
    assert main(["backup", line.url(3), "--model", "jjr5000", "-o", str(file_b)]) == 0
    assert main(["restore", str(file_b), line.url(2), "--model", "jjr5000", "--yes", "--json"]) == 0
    written = [(w["key"], w["new"]) for w in json.loads(capsys.readouterr().out.split("\n", 1)[1])["written"]]
    assert written[-1] == ("parameter_modify", "disabled (0)")
    assert line.starters[2].params == line.starters[3].params


def test_a_failed_write_stops_the_restore_and_puts_the_lock_back(
    line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    file_a = tmp_path / "a.toml"
    main(["backup", line.url(2), "--model", "jjr5000", "-o", str(file_a)])
    starter = line.starters[3]
    write = starter.write

    def sticky(point: PointDef, raw: int) -> None:  # the device acknowledges ramp_time but keeps its value
        if point.key != "ramp_time":
            write(point, raw)

    starter.write = sticky  # type: ignore[method-assign]
    assert main(["restore", str(file_a), line.url(3), "--model", "jjr5000", "--yes"]) == 1
    err = capsys.readouterr().err
    assert "wrote 10 s but read back 20 s" in err and "not sent (an earlier write failed)" in err
    assert starter.params["parameter_modify"] == 0  # lifted for the restore, put back after the failure
    assert starter.params["current_limit"] == 400


def test_backup_of_another_model_is_refused(line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    file_a = tmp_path / "a.toml"
    assert main(["backup", line.url(2), "--model", "jjr5000", "-o", str(file_a)]) == 0
    before = dict(line.starters[4].params)
    line.functions.clear()
    assert main(["restore", str(file_a), line.url(4), "--model", "ssd1", "--yes"]) == 1
    assert "backup of a jjr5000" in capsys.readouterr().err
    assert 6 not in line.functions and line.starters[4].params == before


def test_dry_run_shows_frames_and_sends_nothing(line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    file_a = tmp_path / "a.toml"
    main(["backup", line.url(2), "--model", "jjr5000", "-o", str(file_a)])
    capsys.readouterr()
    line.functions.clear()
    assert main(["restore", str(file_a), line.url(3), "--model", "jjr5000", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "03 06 01 47 00 01 F8 01" in out  # parameter_modify = 1 to unit 3, first
    assert out.index("parameter_modify enabled") < out.index("current_limit 350 %")
    assert 6 not in line.functions and line.starters[3].params["current_limit"] == 400
    assert main(["restore", str(file_a), line.url(3), "--model", "jjr5000", "--dry-run", "--json"]) == 0
    document = json.loads(capsys.readouterr().out)
    assert document["dry_run"] is True and document["device"] == line.url(3)
    assert {"differences", "not_restored"} <= set(document)
    sent = {row["key"]: row for row in document["would_send"]}
    assert sent["current_limit"]["raw"] == 350 and sent["current_limit"]["value"] == "350 %"
    assert sent["parameter_modify"]["frames"] == ["03 06 01 47 00 01 F8 01"]
    assert 6 not in line.functions and line.starters[3].params["current_limit"] == 400


def test_restore_without_yes_and_without_a_terminal_sends_nothing(
    line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    file_a = tmp_path / "a.toml"
    main(["backup", line.url(2), "--model", "jjr5000", "-o", str(file_a)])
    line.functions.clear()
    assert main(["restore", str(file_a), line.url(3), "--model", "jjr5000"]) == 1
    assert "refused without --yes" in capsys.readouterr().err
    assert 6 not in line.functions


def test_uncertain_and_state_rules_are_checked_before_anything_is_sent(
    line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    j8 = line.starters[5]
    file_8 = tmp_path / "j8.toml"
    main(["backup", line.url(5), "--model", "jjr8000", "-o", str(file_8)])
    text = file_8.read_text(encoding="utf-8")
    # p7 current_limit (certain scale, locked while running) and p42, an assumed scale
    assumed = next(p for p in get_profile("jjr8000").parameters if p.scale_assumed and p.writable)
    j8.params["current_limit"] = 400
    j8.params[assumed.key] = assumed.raw_max if j8.params[assumed.key] != assumed.raw_max else assumed.raw_min
    line.functions.clear()
    assert main(["restore", str(file_8), line.url(5), "--model", "jjr8000", "--yes"]) == 1
    assert "--accept-uncertain" in capsys.readouterr().err and 6 not in line.functions

    j8.start()
    assert main(["restore", str(file_8), line.url(5), "--model", "jjr8000", "--yes", "--accept-uncertain"]) == 1
    assert "does not accept changes while the motor is" in capsys.readouterr().err and 6 not in line.functions

    j8.soft_stop()
    j8.params["soft_stop_time"] = 0  # so the motor is stopped on the next read
    file_8.write_text(text, encoding="utf-8")
    assert main(["restore", str(file_8), line.url(5), "--model", "jjr8000", "--yes", "--accept-uncertain"]) == 0
    assert j8.params["current_limit"] == 350 and j8.params[assumed.key] == assumed.default


def test_an_edited_backup_is_checked(tmp_path: Path, line: Line) -> None:
    file_a = tmp_path / "a.toml"
    main(["backup", line.url(2), "--model", "jjr5000", "-o", str(file_a)])
    text = file_a.read_text(encoding="utf-8")
    block = text.index("[parameters.current_limit]")
    edited = text[:block] + text[block:].replace("value = 350", "value = 380", 1)
    file_a.write_text(edited, encoding="utf-8")
    with pytest.raises(ValidationError, match=r"current_limit: value 380 is raw 380 but raw says 350"):
        backups.load(file_a)
    file_a.write_text(edited.replace("raw = 350\n", "", 1), encoding="utf-8")
    taken, _ = backups.load(file_a)
    assert taken.parameters["current_limit"].raw == 380
    file_a.write_text(edited.replace("value = 380", "value = 9000", 1), encoding="utf-8")
    with pytest.raises(ValidationError, match=r"a.toml: current_limit \(0x0103\): 9000 % is out of range"):
        backups.load(file_a)


def test_every_profile_round_trips_through_a_backup_file(tmp_path: Path) -> None:
    for name in ("jjr5000", "ssd1", "jjr8000"):
        profile = get_profile(name)
        raws = {p.key: p.default if p.default is not None else p.raw_max for p in profile.parameters}
        taken = backups.Backup(name, {k: backups.Entry(k, r, "") for k, r in raws.items()})
        backups.save(taken, profile, tmp_path / f"{name}.toml")
        assert backups.load(tmp_path / f"{name}.toml")[0].raws() == raws


def test_a_path_without_parameters_says_so_in_one_line(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    profile = get_profile("jjr5000")
    with (
        open_device("profibus-pkw+sim://?ppo=3", profile) as device,  # PPO3: no PKW channel
        pytest.raises(UnsupportedOperationError, match=r"^profibus-pkw \(.*\) cannot read parameters"),
    ):
        backups.take_backup(device)
    assert main(["backup", "profibus-pkw+sim://?ppo=3", "--model", "jjr5000", "-o", str(tmp_path / "x.toml")]) == 1
    err = capsys.readouterr().err
    assert not (tmp_path / "x.toml").exists()
    assert err.count("\n") == 1 and "cannot read parameters, so it cannot back them up" in err


def test_diff_sides_and_errors(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert parse_spec("modbus-rtu:///dev/ttyUSB0?unit=2@jjr5000").model == "jjr5000"
    assert parse_spec("modbus-rtu:///dev/ttyUSB0?unit=2", "ssd1").model == "ssd1"
    assert parse_spec("defaults@ssd1").kind == "defaults"
    with pytest.raises(ConfigurationError, match="needs its model"):
        parse_spec("modbus-rtu:///dev/ttyUSB0?unit=2")
    assert main(["diff", "defaults@jjr5000", str(tmp_path / "missing.toml")]) == 2
    assert "no such backup file" in capsys.readouterr().err
    assert main(["diff", "defaults@jjr5000", "defaults@ssd1", "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["models"] == ["jjr5000", "ssd1"] and report["differences"]
