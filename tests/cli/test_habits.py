"""The command line as an integrator uses it: --version, device names, pipes, Ctrl-C, decode from files, simulate.

Run through the installed console script (``starterbus``) where the process boundary is the point.
"""

from __future__ import annotations

import json
import os
import pty
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.cli.output import cells, table
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.transports.modbus.codec.crc import append_crc
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

EXE = shutil.which("starterbus") or str(Path(sys.executable).with_name("starterbus"))


def run(*args: str, stdin: str | None = None, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [EXE, *args],
        check=False,
        input=stdin,
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, **(env or {})},
    )


def spawn(*args: str, env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    """The console script in the background, its stdout and stderr piped, and Ctrl-C (SIGINT) handled as in a shell.

    A runner started in the background ignores SIGINT, and a child inherits that: the child gets the default.
    """
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return subprocess.Popen(
            [EXE, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**os.environ, **(env or {})}
        )
    finally:
        signal.signal(signal.SIGINT, previous)


def test_version() -> None:
    result = run("--version")
    assert result.returncode == 0 and result.stdout.startswith("starterbus ") and not result.stderr


def test_a_closed_pipe_ends_quietly() -> None:
    shell = subprocess.run(
        f"'{EXE}' params jjr8000 | head -1; echo \"rc=${{PIPESTATUS[0]}}\"",
        shell=True, executable="/bin/bash", capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert shell.stdout.splitlines()[-1] == "rc=0" and shell.stderr == ""


@pytest.fixture
def fleet(tmp_path: Path) -> Iterator[tuple[Path, dict[int, SimulatedStarter]]]:
    starters = {2: SimulatedStarter(get_profile("jjr5000")), 3: SimulatedStarter(get_profile("ssd1"))}
    sim = ModbusRtuSimulator(starters, pty=True).start()
    port = sim.client_urls()[2].split("://", 1)[1].split("?", 1)[0]
    path = tmp_path / "plant.toml"
    path.write_text(
        f"""
[[bus]]
name = "mcc-1"
url = "modbus-rtu://{port}?timeout=0.3"

  [[bus.device]]
  name = "conveyor-1"
  model = "jjr5000"
  address = 2

  [[bus.device]]
  name = "fan-3"
  model = "ssd1"
  address = 3
""",
        encoding="utf-8",
    )
    try:
        yield path, starters
    finally:
        sim.close()


def test_device_names_from_a_fleet_file(
    fleet: tuple[Path, dict[int, SimulatedStarter]], capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    path, starters = fleet
    assert main(["status", "conveyor-1", "--fleet", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["status"]["state"] == "ready"
    monkeypatch.setenv("STARTERBUS_FLEET", str(path))
    assert main(["read", "fan-3", "ramp_time", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["model"] == "ssd1"
    assert main(["start", "fan-3", "--yes"]) == 0
    assert "start: ok" in capsys.readouterr().out and starters[3].phase.value == "starting"
    assert main(["status", "pump-9"]) == 1
    err = capsys.readouterr().err
    assert "no device named 'pump-9'" in err and "conveyor-1, fan-3" in err
    assert main(["status", "conveyor-1", "--model", "ssd1"]) == 1
    assert "disagrees with the fleet file" in capsys.readouterr().err


def test_the_confirmation_asks_on_stderr_so_stdout_stays_json(
    fleet: tuple[Path, dict[int, SimulatedStarter]], tmp_path: Path
) -> None:
    path, starters = fleet
    terminal, tty = pty.openpty()  # a person at a terminal, the output piped on (`| jq`)
    proc = subprocess.Popen(
        [EXE, "write", "conveyor-1", "ramp_time=12", "--fleet", str(path), "--json",
         "--audit-log", str(tmp_path / "audit.jsonl")],
        stdin=tty, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    os.close(tty)
    try:
        os.write(terminal, b"y\n")  # the answer waits in the terminal's line buffer until the question is read
        out, err = proc.communicate(timeout=60)
    finally:
        os.close(terminal)
    assert proc.returncode == 0, err
    assert "[y/N]" in err and "[y/N]" not in out
    assert [w["key"] for w in json.loads(out)["written"]] == ["ramp_time"]
    assert starters[2].params["ramp_time"] == 12


def test_a_name_without_a_fleet_file_says_how_to_give_one(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.delenv("STARTERBUS_FLEET", raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))
    assert main(["status", "conveyor-1"]) == 1
    err = capsys.readouterr().err
    assert "--fleet FILE" in err and "STARTERBUS_FLEET" in err and len(err.strip().splitlines()) == 1
    (tmp_path / "starterbus").mkdir()
    (tmp_path / "starterbus" / "config.toml").write_text('fleet = "/nowhere/plant.toml"\n', encoding="utf-8")
    assert main(["status", "conveyor-1"]) == 1
    assert "/nowhere/plant.toml" in capsys.readouterr().err


def test_validate_opens_nothing(fleet: tuple[Path, dict[int, SimulatedStarter]], tmp_path: Path) -> None:
    path, _ = fleet
    result = run("validate", str(path), "examples/fleet.toml", "--json")
    assert result.returncode == 0, result.stderr
    files = json.loads(result.stdout)
    assert [len(f["devices"]) for f in files] == [2, 5]  # /dev/ttyUSB0 etc. were never opened
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[[bus]]\nname = "x"\nurl = "modbus-rtu:///dev/null"\n  [[bus.device]]\n  name = "a"\n  model = "nope"\n'
    )
    result = run("validate", str(bad))
    assert result.returncode == 1 and "bad.toml" in result.stderr and "nope" in result.stderr


def test_watch_once(fleet: tuple[Path, dict[int, SimulatedStarter]]) -> None:
    path, _ = fleet
    result = run("watch", "conveyor-1", "--fleet", str(path), "--once")
    assert result.returncode == 0, result.stderr
    assert "ready" in result.stdout and "phase_a_current" in result.stdout
    result = run("watch", "conveyor-1", "--fleet", str(path), "--count", "2", "--interval", "0", "--json")
    states = [json.loads(line)["status"]["state"] for line in result.stdout.splitlines()]  # JSON lines
    assert result.returncode == 0 and states == ["ready", "ready"]


def test_a_virtual_can_bus_from_a_shell_fails_at_once_saying_why() -> None:
    result = run("status", "devicenet://virtual/bus0?mac=5", "--model", "jjr8000")
    assert result.returncode == 1 and result.stdout == ""
    assert len(result.stderr.strip().splitlines()) == 1
    assert "virtual channel 'bus0'" in result.stderr and "exists only inside one process" in result.stderr
    assert "devicenet://remote/127.0.0.1:54701?mac=N" in result.stderr


def test_decode_from_stdin_and_candump_logs(tmp_path: Path) -> None:
    answer = append_crc(bytes.fromhex("02 03 02 01 86")).hex(" ")
    result = run("decode", "modbus-rtu", stdin=f"# a hex dump\n02 03 01 00 00 01 85 C5\n\n{answer}\n")
    assert result.returncode == 0, result.stderr
    assert result.stdout.count("unit 2") >= 2
    log = tmp_path / "candump.log"
    log.write_text("(1700000000.000100) can0 42E#004B03010300\n(1700000000.000200) can0 42B#00940C01\n")
    result = run("decode", "devicenet", "--model", "jjr8000", "--file", str(log), "--json")
    assert result.returncode == 0, result.stderr
    assert [a["title"].split()[0] for a in json.loads(result.stdout)] == ["42E#004B03010300", "42B#00940C01"]
    result = run("decode", "devicenet", "-f", str(tmp_path / "missing.log"))
    assert result.returncode == 1 and "missing.log" in result.stderr


def test_simulate_several_models_on_one_line_with_a_fault_script(tmp_path: Path) -> None:
    script = tmp_path / "s.txt"
    script.write_text("0 2 fault 6   # trip at once\n")
    proc = spawn(
        "simulate", "--unit", "2:jjr5000", "--unit", "3:ssd1", "--modbus-rtu", "PTY", "--script", str(script), "--json"
    )
    try:
        assert proc.stdout is not None and proc.stderr is not None
        listing = json.loads(proc.stdout.readline())
        assert listing["units"] == {"2": "jjr5000", "3": "ssd1"}
        assert "fault 6 (motor overload)" in proc.stderr.readline()
        urls = listing["front_ends"][0]["urls"]
        status = run("status", urls["2"], "--model", "jjr5000", "--json")
        assert json.loads(status.stdout)["status"]["fault_code"] == 6
        read = run("read", urls["3"], "--model", "ssd1", "ramp_time", "--json")
        assert read.returncode == 0, read.stderr
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 130
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_bad_scripts_name_the_line(tmp_path: Path) -> None:
    script = tmp_path / "s.txt"
    script.write_text("1 2 fault 6\n2 9 start\n")
    result = run("simulate", "--unit", "2:jjr5000", "--modbus-rtu", "PTY", "--script", str(script))
    assert result.returncode == 1 and f"{script}:2: unit 9 is not simulated" in result.stderr


def test_tables_count_display_cells() -> None:
    assert cells("电机额定电流") == 12 and cells("motor") == 5
    import io

    out = io.StringIO()
    table(["名称", "unit"], [["电机额定电流", "A"], ["ramp", "s"]], out)
    lines = out.getvalue().splitlines()
    assert len({cells(line[: line.rindex(" ") + 1]) for line in lines[:1] + lines[2:]}) == 1  # columns line up
