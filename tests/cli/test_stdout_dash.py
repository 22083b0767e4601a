"""``-`` as an output file is standard output, as with every tool: ``poll --csv -`` and ``backup -o -`` write
their CSV or TOML to stdout (and nothing else there), never a file named ``-``; with ``--json`` it is refused."""

from __future__ import annotations

import csv
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from starterbus.cli.main import main

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

EXE = shutil.which("starterbus") or str(Path(sys.executable).with_name("starterbus"))
SIM = "profibus-pkw+sim://?ppo=1"  # a private in-process simulated starter with a parameter channel

FLEET = f"""
[[bus]]
name = "dp"
url = "{SIM}"

  [[bus.device]]
  name = "mixer"
  model = "jjr5000"
  address = 5
"""


@pytest.fixture
def fleet(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.chdir(tmp_path)  # a file named "-" would appear here
    path = tmp_path / "plant.toml"
    path.write_text(FLEET, encoding="utf-8")
    return path


def test_poll_csv_dash_is_stdout_and_only_the_csv(fleet: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["poll", str(fleet), "--once", "--csv", "-"]) == 0
    out = capsys.readouterr().out
    rows = list(csv.DictReader(out.splitlines()))
    assert [(r["device"], r["online"], r["state"]) for r in rows] == [("mixer", "1", "ready")]  # no table around it
    assert not (fleet.parent / "-").exists()


def test_backup_dash_is_stdout(fleet: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["backup", SIM, "--model", "jjr5000", "-o", "-"]) == 0
    out, err = capsys.readouterr()
    data = tomllib.loads(out)
    assert data["model"] == "jjr5000" and data["parameters"]
    assert err.count("\n") == 1 and "written to stdout" in err
    assert not (fleet.parent / "-").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["poll", "{fleet}", "--once", "--csv", "-", "--json"], "--csv - and --json both write to standard output"),
        (["backup", SIM, "--model", "jjr5000", "-o", "-", "--json"], "-o - and --json both write to standard output"),
    ],
    ids=["poll", "backup"],
)
def test_dash_and_json_together_are_refused(
    argv: list[str], message: str, fleet: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([a.format(fleet=fleet) for a in argv]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and message in err


def test_a_closed_pipe_ends_the_csv_stream_quietly(fleet: Path) -> None:
    # the timeout, below --duration, fails the test if the stream outlives its reader
    shell = subprocess.run(
        f"'{EXE}' poll '{fleet}' --csv - --duration 120 | head -2; echo \"rc=${{PIPESTATUS[0]}}\"",
        shell=True,
        executable="/bin/bash",
        capture_output=True,
        text=True,
        timeout=100,
        check=False,
    )
    lines = shell.stdout.splitlines()
    assert lines[0].startswith("time,device,bus,model") and lines[-1] == "rc=0" and shell.stderr == ""
