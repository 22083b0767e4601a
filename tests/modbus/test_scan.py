"""``starterbus scan`` finds the units of a simulated line at the one speed and parity they answer at, tells
their models from their registers, and writes a fleet file that ``validate`` accepts and ``poll --once`` reads.

The simulator answers only a client at its own speed and parity (``strict_line``): a pty keeps the speed the
client set but no parity, so the parity the client opened the port with is handed to it (``client_parity``)."""

from __future__ import annotations

import json
import os
import termios
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.transports.modbus.codec.frames import ExceptionResponse, ReadRequest, ReadResponse
from starterbus.transports.modbus.driver import link
from starterbus.transports.modbus.scan import identify
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator
from starterbus.transports.modbus.slave import SlaveLogic

MODELS = ("jjr5000", "ssd1", "jjr8000")


def another_speed(path: str) -> None:
    """Set the pty to 9600 baud. Linux applies no parity to a pty and refuses (EINVAL) a tcsetattr that changes
    nothing it can apply: a port opened again at the speed and parity of the last client would fail."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    try:
        attributes = termios.tcgetattr(fd)
        attributes[4] = attributes[5] = termios.B9600
        termios.tcsetattr(fd, termios.TCSANOW, attributes)
    finally:
        os.close(fd)


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def test_scan_writes_a_fleet_file_that_validates_and_polls(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    starters = {
        3: SimulatedStarter(get_profile("jjr5000"), values={"slave_address": 3}),
        6: SimulatedStarter(get_profile("ssd1"), values={"slave_address": 6}),
        7: SimulatedStarter(get_profile("jjr8000"), values={"slave_address": 7}),
    }
    opened: list[str] = []
    real_open = link.open_pyserial

    def open_pyserial(target: str, settings: link.SerialSettings, *, url: bool = False) -> object:
        opened.append(settings.parity)
        return real_open(target, settings, url=url)

    monkeypatch.setattr(link, "open_pyserial", open_pyserial)
    fleet = tmp_path / "fleet.toml"
    with ModbusRtuSimulator(starters, pty=True, baudrate=19200, parity="E", strict_line=True) as sim:
        sim.client_parity = lambda: opened[-1] if opened else None
        port = f"modbus-rtu://{sim.client_path}"
        code, out, err = run(capsys, "scan", port, "--units", "1-8", "--baudrates", "9600,19200", "--parities",
                             "N,O,E", "--timeout", "0.05", "-o", str(fleet), "--json")  # fmt: skip
        assert code == 0, err
        found = json.loads(out)["found"]
        assert [(f["unit"], f["baudrate"], f["parity"], f["model"]) for f in found] == [
            (3, 19200, "E", "jjr5000"), (6, 19200, "E", "ssd1"), (7, 19200, "E", "jjr8000"),
        ]  # fmt: skip
        assert "scan: 9600 8N1" in err and "unit 3: jjr5000" in err  # progress on stderr
        assert sorted(set(opened)) == ["E", "N", "O"]  # every parity was tried; only E answered
        assert run(capsys, "validate", str(fleet))[0] == 0
        another_speed(sim.client_path)
        code, out, err = run(capsys, "poll", str(fleet), "--once", "--json")
        assert code == 0, err
        samples = [json.loads(line) for line in out.splitlines()]
        assert sorted((s["device"], s["online"]) for s in samples) == [
            ("jjr5000-3", True), ("jjr8000-7", True), ("ssd1-6", True),
        ]  # fmt: skip
        code, _, err = run(capsys, "scan", port, "--units", "1-2", "--baudrates", "19200", "-o", str(fleet))
        assert code == 1 and "exists" in err and "nothing done" in err


def test_each_model_is_told_from_its_registers() -> None:
    profiles = [get_profile(m) for m in MODELS]
    for model in MODELS:
        logic = SlaveLogic({9: SimulatedStarter(get_profile(model), values={"slave_address": 9})})

        def read(address: int, logic: SlaveLogic = logic) -> int | ExceptionResponse:
            answer = logic.handle(ReadRequest(9, address, 1))
            assert isinstance(answer, ReadResponse | ExceptionResponse)
            return answer.values[0] if isinstance(answer, ReadResponse) else answer

        assert identify(read, 9, profiles)[0] == model
        assert identify(read, 10, profiles)[0] is None  # its slave-address register says 9, not 10
