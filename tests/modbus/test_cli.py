"""The CLI with Modbus: read/write/status/start/stop/reset/decode in-process, simulate as a real subprocess."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from typing import TYPE_CHECKING

import pytest

from starterbus.cli.main import main
from starterbus.core.simulator import Phase, SimulatedStarter

if TYPE_CHECKING:
    from starterbus.tests.modbus.conftest import SimFactory, Vector


def phase(starter: SimulatedStarter) -> Phase:
    """The motor state now (a call, so that type checkers do not narrow it between commands)."""
    return starter.phase


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_read_table_and_json(make_sim: SimFactory, capsys: pytest.CaptureFixture[str]) -> None:
    sim = make_sim("jjr5000")
    sim.starters[2].params["motor_rated_current"] = 390
    code, out, _ = run(capsys, "read", sim.url(2), "motor_rated_current", "0x0103", "--model", "jjr5000")
    assert code == 0
    lines = out.splitlines()
    assert lines[0].split() == ["address", "key", "name", "value", "raw"]
    assert any("motor_rated_current" in line and "390 A" in line for line in lines)
    code, out, _ = run(capsys, "read", sim.url(2), "status_word", "phase_a_current", "--model", "jjr5000", "--json")
    data = json.loads(out)
    assert code == 0 and [v["key"] for v in data["values"]] == ["status_word", "phase_a_current"]
    assert data["values"][1]["resolution"] == pytest.approx(0.1)


def test_write_validates_then_writes_and_reads_back(make_sim: SimFactory, capsys: pytest.CaptureFixture[str]) -> None:
    sim = make_sim("ssd1")
    url = sim.url(2)
    code, out, _ = run(capsys, "write", url, "--model", "ssd1", "--yes", "current_limit=380", "start_mode=voltage ramp")
    assert code == 0, out
    assert sim.starters[2].params["current_limit"] == 380
    requests = sim.counters.requests
    code, _, err = run(capsys, "write", url, "--model", "ssd1", "--yes", "ramp_time=12", "current_limit=9000")
    assert code == 1 and "current_limit" in err and "out of range" in err and err.count("\n") == 1
    assert sim.counters.requests == requests  # nothing was sent, not even the valid first assignment
    code, out, _ = run(capsys, "write", url, "--model", "ssd1", "--dry-run", "current_limit=380")
    assert code == 0 and "02 06 01 03 01 7C 78 74" in out and sim.counters.requests == requests


def test_status_and_commands(make_sim: SimFactory, capsys: pytest.CaptureFixture[str]) -> None:
    sim = make_sim("jjr8000")
    starter = sim.starters[2]
    url = sim.url(2)
    code, out, _ = run(capsys, "status", url, "--model", "jjr8000")
    assert code == 0 and "ready" in out and "current A" in out
    code, out, _ = run(capsys, "start", url, "--model", "jjr8000", "--yes", "--json", "--show-status")
    assert code == 0 and json.loads(out)["status"]["state"] == "starting"
    assert phase(starter) is Phase.STARTING and starter.control_word == 0x0009
    code, out, _ = run(capsys, "stop", url, "--model", "jjr8000", "--yes")
    assert code == 0 and starter.control_word == 0x0008
    starter.inject_fault(7)
    code, out, _ = run(capsys, "status", url, "--model", "jjr8000", "--json")
    status = json.loads(out)["status"]
    assert status["fault_code"] == 7 and status["fault_text"] == "motor locked rotor"
    code, out, _ = run(capsys, "reset", url, "--model", "jjr8000", "--yes")
    assert code == 0 and phase(starter) is Phase.STOPPED
    code, out, _ = run(capsys, "start", url, "--model", "jjr8000", "--dry-run")
    assert code == 0 and "02 06 00 00 00 09 49 FF" in out


def test_errors_are_one_line_and_non_zero(make_sim: SimFactory, capsys: pytest.CaptureFixture[str]) -> None:
    sim = make_sim("jjr5000")
    for argv, words in [
        (["read", sim.url(2, colour="red"), "--model", "jjr5000"], "unknown URL parameter"),
        (["read", sim.url(7, timeout=0.05, retries=0), "ramp_time", "--model", "jjr5000"], "no answer from unit 7"),
        (["read", sim.url(2), "0x0107", "--model", "jjr5000"], "no parameter or measurement"),
        (["read", "modbus-rtu:///dev/nonexistent?unit=2", "--model", "jjr5000"], "cannot open serial port"),
    ]:
        code, _, err = run(capsys, *argv)
        assert code != 0 and words in err and err.count("\n") == 1, err


def test_decode_golden_vectors(golden: Vector, capsys: pytest.CaptureFixture[str]) -> None:
    model = golden.models[0]
    code, out, _ = run(
        capsys, "decode", "modbus-rtu", "--model", model, "--json",
        *golden.request_frame.hex(" ").upper().split(), *golden.response_frame.hex(" ").upper().split(),
    )  # fmt: skip
    annotations = json.loads(out)
    assert annotations[0]["title"].startswith("request") and annotations[0]["error"] is None
    if golden.response is None:
        assert code == 1 and annotations[1]["error"] and "malformed" in annotations[1]["title"]
    else:
        assert code == 0 and annotations[1]["error"] is None
    meanings = " ".join(f["meaning"] for a in annotations for f in a["fields"])
    if golden.engineering is not None:
        assert str(golden.engineering) in meanings
    if golden.status == "fault 6 motor overload":
        assert "fault 6: motor overload" in meanings


def test_decode_manual_frames_without_crc(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "decode", "modbus-rtu", "--model", "jjr8000", "--no-crc", "02", "03", "02", "00", "EB",
                       "--address", "2")  # fmt: skip
    assert code == 0 and "23.5 A" in out and "on the wire append BC 0B" in out
    code, out, _ = run(capsys, "decode", "modbus-rtu", "--model", "jjr8000", "02 03 00 01 00 01")
    assert code == 1 and "--no-crc" in out  # a frame printed without CRC is recognised as such
    code, out, _ = run(capsys, "decode", "modbus-rtu", "--model", "jjr5000", "02 03 01 00 00 01 85 C6")
    assert code == 1 and "right CRC is 85 C5" in out
    code, out, _ = run(capsys, "decode", "modbus-rtu", "--model", "jjr5000", "028604B3A3")
    assert code == 0 and "exception code" in out and "parameter modif" in out
    code, out, _ = run(capsys, "decode", "modbus-rtu", "--model", "jjr5000", "--direction", "response",
                       "02 06 01 03 01 7C 78 74")  # fmt: skip
    assert code == 0 and "confirmed" in out and "380 %" in out
    code, out, _ = run(capsys, "decode", "modbus-rtu", "--model", "jjr5000", "02 06 01 03 03 E8 78 E3")
    assert "outside" in out and "exception 03" in out  # annotates what the device will say to a bad value
    code, _, err = run(capsys, "decode", "modbus-rtu", "0x02 0x0G")
    assert code == 1 and "not hex" in err


def test_simulate_subprocess_prints_the_pty_and_serves(capsys: pytest.CaptureFixture[str]) -> None:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "starterbus.cli.main", "simulate", "--model", "jjr5000", "--unit", "2", "--unit", "3",
         "--modbus-rtu", "PTY", "--baudrate", "19200", "--parity", "N", "--stopbits", "2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().strip()
        assert line.startswith("modbus-rtu: /dev/pts/"), line
        path = line.split(": ", 1)[1]
        for unit in (2, 3):
            url = f"modbus-rtu://{path}?unit={unit}&baudrate=19200&parity=N&stopbits=2"
            code, out, err = run(capsys, "read", url, "motor_rated_current", "--model", "jjr5000", "--json")
            assert code == 0, err
            assert json.loads(out)["values"][0]["key"] == "motor_rated_current"
        code, _, err = run(capsys, "write", f"modbus-rtu://{path}?unit=3&baudrate=19200&parity=N&stopbits=2", "--model",
                           "jjr5000", "--yes", "ramp_time=15")  # fmt: skip
        assert code == 0, err
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, proc.stderr.read() if proc.stderr else ""


def test_simulate_rejects_bad_options(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "simulate", "--model", "ssd1", "--unit", "246", "--modbus-rtu", "PTY", "--duration", "0")
    assert code == 1 and "1..245" in err
    code, _, err = run(capsys, "simulate", "--model", "jjr8000", "--modbus-rtu", "PTY", "--baudrate", "38400")
    assert code == 1 and "19200" in err
    code, _, err = run(capsys, "simulate", "--model", "jjr5000", "--modbus-rtu-tcp", "nonsense")
    assert code == 1 and "HOST:PORT" in err


def test_simulate_tcp_in_process(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "simulate", "--model", "jjr5000", "--modbus-rtu-tcp", "127.0.0.1:0", "--duration", "0")
    assert code == 0, err
    assert out.startswith("modbus-rtu-tcp: 127.0.0.1:")
