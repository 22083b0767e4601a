"""``starterbus simulate --modbus-tcp``: several units behind one simulated gateway, served to the CLI."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest

from starterbus.cli.main import main


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_simulate_serves_several_units_over_modbus_tcp(capsys: pytest.CaptureFixture[str]) -> None:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "starterbus.cli.main", "simulate", "--unit", "2:jjr5000", "--unit", "3:ssd1",
         "--modbus-tcp", "127.0.0.1:0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().strip()
        assert line.startswith("modbus-tcp: 127.0.0.1:"), line
        where = line.split(": ", 1)[1]
        for unit, model in ((2, "jjr5000"), (3, "ssd1")):
            code, out, err = run(
                capsys, "read", f"modbus-tcp://{where}?unit={unit}", "ramp_time", "--model", model, "--json"
            )
            assert code == 0, err
            assert json.loads(out)["values"][0]["raw"] == 10
        code, _, err = run(capsys, "write", f"modbus-tcp://{where}?unit=3", "--model", "ssd1", "--yes", "ramp_time=15")
        assert code == 0, err
        code, _, err = run(capsys, "status", f"modbus-tcp://{where}?unit=4", "--model", "ssd1")
        assert code == 1 and "unreachable" in err and "\n" not in err.strip()  # 0x0B: one line, no answer
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, proc.stderr.read() if proc.stderr else ""


def test_simulate_refuses_a_unit_the_model_does_not_have(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "simulate", "--unit", "246:ssd1", "--modbus-tcp", "127.0.0.1:0", "--duration", "0")
    assert code == 1 and "1..245" in err
