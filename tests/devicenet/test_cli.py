"""The common CLI commands through devicenet:// URLs, `identify`, `decode devicenet`, `simulate --devicenet`,
and the loopback bridge from another process."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import threading
import types
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from can.interfaces import virtual

from starterbus.cli import simulate as simulate_command
from starterbus.cli.main import main
from starterbus.core import Phase, Profile, SimulatedStarter, open_device
from starterbus.transports.devicenet.simulator import DeviceNetSlaveSimulator

FAST = "dup_mac_wait=0.05&epr=50&poll=10"
# timeout=2 in the URLs below (was 0.5): on a loaded machine a read with control=open right after another command
# once waited longer than 0.5 s for a status parameter ("connection releasing an old allocation")


@pytest.fixture
def simulated(channel: str, jjr8000: Profile) -> Iterator[SimulatedStarter]:
    starter = SimulatedStarter(jjr8000)
    with DeviceNetSlaveSimulator(starter, ("virtual", channel), 5, dup_mac_wait=0.05):
        yield starter


def test_status_read_identify(channel: str, simulated: SimulatedStarter, capsys: pytest.CaptureFixture[str]) -> None:
    url = f"devicenet://virtual/{channel}?mac=5&{FAST}&timeout=2"
    assert main(["status", url, "--model", "jjr8000", "--json"]) == 0
    status = json.loads(capsys.readouterr().out)["status"]
    # a read monitors over explicit messaging: nobody controls the starter over the network
    assert status["state"] == "stopped" and status["ready"] is None and status["bus_control"] is False
    assert status["currents"]["a"]["resolution"] == 1.0
    assert main(["read", url, "m3", "--model", "jjr8000"]) == 1
    assert "control=open" in capsys.readouterr().err  # a status parameter needs the I/O connection
    assert simulated.control_word == 0  # nothing was sent to the starter's control
    assert main(["read", url + "&control=open", "m3", "status_word", "--model", "jjr8000"]) == 0
    out = capsys.readouterr().out
    assert "phase B current" in out and "0x6000" in out
    assert main(["identify", url, "--model", "jjr8000"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"product_name\s+JJR8000", out) and re.search(r"vendor_id\s+819", out)
    assert main(["read", url, "p3", "--model", "jjr8000"]) == 1
    assert "cannot read parameters" in capsys.readouterr().err


def test_identify_by_device_name(
    channel: str, simulated: SimulatedStarter, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    plant = tmp_path / "plant.toml"
    plant.write_text(
        f'[[bus]]\nname = "dn"\nurl = "devicenet://virtual/{channel}?dup_mac_wait=0.05&timeout=0.5"\n'
        'device = [{ name = "crusher", model = "jjr8000", address = 5 }]\n',
        encoding="utf-8",
    )
    assert main(["identify", "crusher", "--fleet", str(plant), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["identity"]["product_name"] == "JJR8000"


def test_commands(
    channel: str, simulated: SimulatedStarter, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    url = f"devicenet://virtual/{channel}?mac=5&{FAST}&timeout=2"
    log = str(tmp_path / "audit.jsonl")
    assert main(["start", url, "--model", "jjr8000", "--dry-run"]) == 0
    assert "42D#0101" in capsys.readouterr().out
    assert simulated.phase is Phase.STOPPED  # a dry run sends nothing
    # a one-shot start would die with the connection: refused in one line, nothing sent
    assert main(["start", url, "--model", "jjr8000", "--yes", "--audit-log", log]) == 1
    err = capsys.readouterr().err
    assert "--hold" in err and "watchdog" in err and len(err.strip().splitlines()) == 1
    assert simulated.start_count == 0
    # held: started (the state reached is reported), then soft-stopped when the hold ends, both audited
    assert main(["start", url, "--model", "jjr8000", "--yes", "--audit-log", log, "--hold-for", "0", "--json"]) == 0
    out, docs, decoder = capsys.readouterr().out, [], json.JSONDecoder()
    while out.strip():
        doc, end = decoder.raw_decode(out.strip())
        docs.append(doc)
        out = out.strip()[end:]
    assert simulated.start_count == 1 and simulated.phase in (Phase.STOPPING, Phase.STOPPED)
    entries = [json.loads(x) for x in Path(log).read_text(encoding="utf-8").splitlines()]
    assert [(e["command"], e["result"]) for e in entries] == [("start", "ok"), ("stop", "ok")]
    assert entries[0]["reached"] in ("starting", "running") and entries[1]["reached"] in ("stopping", "stopped")
    assert [d.get("reached") for d in docs if "reached" in d][:1] in (["starting"], ["running"])
    assert docs[-1]["action"] == "stop" and docs[-1]["result"] == "ok"
    simulated.inject_fault(2)
    assert main(["reset", url, "--model", "jjr8000", "--yes", "--audit-log", log, "--show-status"]) == 0
    assert simulated.fault_code is None
    capsys.readouterr()


def test_decode_command(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["decode", "devicenet", "--model", "jjr8000", "42E#004B03010300", "42B#00940C01"]) == 0
    out = capsys.readouterr().out
    assert "explicit + polled" in out and "object state conflict" in out
    assert main(["decode", "devicenet", "42B#8081"]) == 1
    assert "without a first fragment" in capsys.readouterr().out


def test_simulate_command_in_process(
    channel: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, until: Callable[..., bool]
) -> None:
    """The command runs until its stop event is set (as SIGTERM does), so a cold start cannot outlive it."""
    stops: list[threading.Event] = []

    class RecordedEvent(threading.Event):
        def __init__(self) -> None:
            super().__init__()
            stops.append(self)

    fake_threading = types.SimpleNamespace(
        Event=RecordedEvent, current_thread=threading.current_thread, main_thread=threading.main_thread
    )
    monkeypatch.setattr(simulate_command, "threading", fake_threading)
    args = ["simulate", "--model", "jjr8000", "--unit", "1", "--unit", "2", "--mac", "5", "--mac", "6",
            "--devicenet", f"virtual:{channel}", "--devicenet-dup-mac-wait", "0.05", "--duration", "60"]  # fmt: skip
    result: list[int] = []
    runner = threading.Thread(target=lambda: result.append(main(args)))
    runner.start()
    try:
        assert until(lambda: bool(virtual.channels.get(channel)), 30.0), "the simulator's bus did not open"
        with open_device(f"devicenet://virtual/{channel}?mac=6&{FAST}&timeout=1", "jjr8000") as device:
            assert device.status().source == "devicenet"
    finally:
        assert until(lambda: bool(stops), 30.0), "the simulate command did not start"
        stops[0].set()
        runner.join()
    assert result == [0]
    out = capsys.readouterr().out
    assert "MAC 5" in out and "MAC 6" in out and "extended assemblies 101/102" in out


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--devicenet", "virtual:x", "--mac", "5", "--mac", "6"], "one --mac per --unit"),
        (["--devicenet", "virtual:x", "--mac", "64"], "outside 1..63"),
        (["--devicenet", "virtualx", "--mac", "5"], "INTERFACE:CHANNEL"),
        (["--devicenet", "virtual:x", "--mac", "5", "--devicenet-bridge", "10.1.2.3:5000"], "not a loopback"),
        (["--mac", "5"], "need --devicenet"),
    ],
)
def test_simulate_refuses(extra: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "--model", "jjr8000", "--duration", "0.1", *extra]) == 1
    assert message in capsys.readouterr().err


def test_bridge_from_another_process(capsys: pytest.CaptureFixture[str]) -> None:
    """The simulator runs in a child process; this process reaches it through the loopback bridge."""
    command = [sys.executable, "-m", "starterbus.cli.main", "simulate", "--model", "jjr8000", "--mac", "5",
               "--devicenet", "virtual:bridged", "--devicenet-bridge", "127.0.0.1:0",
               "--devicenet-dup-mac-wait", "0.05", "--duration", "30"]  # fmt: skip
    child = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None
        address = None
        for _ in range(5):
            line = child.stdout.readline()
            match = re.search(r"devicenet://remote/(127\.0\.0\.1:\d+)", line)
            if match:
                address = match.group(1)
                break
        assert address is not None, "the simulator did not print the bridge address"
        url = f"devicenet://remote/{address}?mac=5&{FAST}&timeout=1"
        assert main(["status", url, "--model", "jjr8000", "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["status"]["state"] == "stopped"
        assert main(["identify", url, "--model", "jjr8000", "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["identity"]["product_name"] == "JJR8000"
    finally:
        child.terminate()
        child.wait(10)
    assert child.returncode == 0, child.stderr.read() if child.stderr else ""


def test_identify_right_after_other_commands(
    channel: str, simulated: SimulatedStarter, capsys: pytest.CaptureFixture[str]
) -> None:
    """Each command opens, monitors and releases its own connection set: the next one (here identify) finds
    the slave free at once, never "no explicit connection" (seen once when reads allocated the I/O too)."""
    url = f"devicenet://virtual/{channel}?mac=5&{FAST}&timeout=2"
    for _ in range(5):
        assert main(["status", url, "--model", "jjr8000", "--json"]) == 0
        capsys.readouterr()
        assert main(["identify", url, "--model", "jjr8000", "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["identity"]["product_name"] == "JJR8000"
    assert simulated.control_writes == []
