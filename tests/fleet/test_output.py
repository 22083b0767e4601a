"""What an operator reads: the states' one names, errors apart from faults and never cut mid-word, colour only
on a terminal (and never with NO_COLOR), CSV in wide format with ISO 8601 times, pure JSON on stdout."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from starterbus.cli.output import table, use_colour
from starterbus.core.errors import ConfigurationError
from starterbus.core.model import Value
from starterbus.core.registry import get_profile
from starterbus.core.status import Status
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.output import CsvLog, display_state, shorten

EXE = shutil.which("starterbus") or str(Path(sys.executable).with_name("starterbus"))


def status(**flags: object) -> Status:
    base: dict[str, object] = {"fault": False, "fault_code": None, "fault_text": None, "starting": False,
                               "running": False, "stopping": False}  # fmt: skip
    return Status(**(base | flags))  # type: ignore[arg-type]


def test_idle_reads_ready_only_when_the_device_says_so() -> None:
    assert display_state(status(ready=True)) == "ready"  # Modbus, Profibus: bit 13 "ready to start"
    assert display_state(status(ready=False)) == "stopped"
    assert display_state(status(ready=None)) == "stopped"  # DeviceNet assemblies do not tell
    assert display_state(status(running=True)) == "running"


def test_errors_are_shortened_at_a_word_boundary() -> None:
    text = "/dev/ttyUSB0: no answer from unit 2 within 0.3 s to 02 03 01 00 00 01 85 C5 (attempt 3 of 3)"
    short = shorten(text)
    assert short.endswith(" …") and len(short) <= 48
    assert short.removesuffix(" …") == text[: len(short.removesuffix(" …"))] and text[len(short) - 2] == " "


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_colour_only_on_a_terminal_and_not_with_no_color(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("NO_COLOR", raising=False)
    out = Tty()
    table(["device", "state"], [["crusher", "fault"], ["mill", "running"]], out, styles=["fault", None])
    assert "\x1b[1;31mcrusher" in out.getvalue() and "\x1b" not in out.getvalue().splitlines()[3]
    assert not use_colour(io.StringIO())
    monkeypatch.setenv("NO_COLOR", "1")
    out = Tty()
    table(["device"], [["crusher"]], out, styles=["fault"])
    assert "\x1b" not in out.getvalue()


FLEET = """
[[bus]]
name = "l1"
url = "modbus-rtu:///dev/null"
  [[bus.device]]
  name = "a"
  model = "jjr5000"
  address = 2
  parameters = ["current_limit"]
"""


def test_wide_csv_refuses_to_append_another_layout(tmp_path: Path) -> None:
    path = tmp_path / "log.csv"
    CsvLog(path, parse_fleet(FLEET, "f.toml")).close()
    assert path.read_text(encoding="utf-8").startswith("time,device,bus,model,online,state,ready,fault_code")
    assert "phase_a_current,phase_b_current,phase_c_current,current_limit" in path.read_text(encoding="utf-8")
    with pytest.raises(ConfigurationError, match="another layout"):
        CsvLog(path, long=True)


def test_demo_json_is_pure_json() -> None:
    result = subprocess.run(
        [EXE, "demo", "--duration", "2", "--json"], capture_output=True, text=True, timeout=120, check=False,
        env={**os.environ, "STARTERBUS_AUDIT_LOG": os.devnull},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines and all(isinstance(json.loads(line), dict) for line in lines)
    assert "states seen per device" in result.stderr


def test_value_text_is_used_for_points() -> None:
    point = get_profile("jjr5000").point("current_limit")
    assert Value.from_raw(point, 380).text() == "380 %"


def test_json_into_a_closed_pipe_ends_quietly() -> None:
    shell = subprocess.run(
        f"'{EXE}' demo --duration 2 --json | head -1 > /dev/null; echo \"rc=${{PIPESTATUS[0]}}\"",
        shell=True, executable="/bin/bash", capture_output=True, text=True, timeout=120, check=False,
        env={**os.environ, "STARTERBUS_AUDIT_LOG": os.devnull},
    )  # fmt: skip
    assert shell.stdout.strip() == "rc=0"
    assert "Traceback" not in shell.stderr and "BrokenPipe" not in shell.stderr
