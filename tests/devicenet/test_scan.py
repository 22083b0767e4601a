"""``starterbus scan devicenet://virtual/CHANNEL`` finds the two simulated nodes with their identity objects,
writes a fleet file that ``validate`` accepts and ``poll --once`` reads, and no control output (no polled I/O
connection, no run bit) reaches either starter: one of them keeps running through the scan."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.core.profile import Profile
from starterbus.core.simulator import ManualClock, Phase, SimulatedStarter
from starterbus.transports.devicenet.codec.ids import poll_command_id
from starterbus.transports.devicenet.simulator import DeviceNetSimulator

FAST = "dup_mac_wait=0.05"


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def two_nodes(jjr8000: Profile, channel: str) -> Iterator[dict[int, SimulatedStarter]]:
    starters = {3: SimulatedStarter(jjr8000, ManualClock(0.0)), 7: SimulatedStarter(jjr8000, ManualClock(0.0))}
    starters[7].start("keypad")  # running from elsewhere: a stray run = 0 would stop it
    sim = DeviceNetSimulator(("virtual", channel), dup_mac_wait=0.05)
    for mac, starter in starters.items():
        sim.add_node(starter, mac)
    with sim:
        yield starters


def test_scan_lists_the_nodes_and_sends_no_control_output(
    two_nodes: dict[int, SimulatedStarter], channel: str, sniffer: object, tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    fleet = tmp_path / "dn.toml"
    url = f"devicenet://virtual/{channel}?{FAST}"
    code, out, err = run(capsys, "scan", url, "--macs", "1-9", "--timeout", "0.1", "-o", str(fleet), "--json")
    assert code == 0, err
    found = json.loads(out)["found"]
    assert [(n["mac"], n["model"]) for n in found] == [(3, "jjr8000"), (7, "jjr8000")]
    assert found[0]["identity"]["product_name"] == "JJR8000" and found[1]["identity"]["serial_number"] == "0x20110107"
    assert "scan: MAC 5" in err and "MAC 7: jjr8000" in err  # progress on stderr
    for starter in two_nodes.values():
        assert starter.control_writes == []
    assert two_nodes[7].phase is Phase.STARTING or two_nodes[7].phase is Phase.RUNNING
    polls = [t for t in sniffer.texts() if int(t.partition("#")[0], 16) in (poll_command_id(3), poll_command_id(7))]  # type: ignore[attr-defined]
    assert polls == []  # the polled I/O connection was never used
    assert "address = 3" in fleet.read_text(encoding="utf-8") and "mac=" not in fleet.read_text(encoding="utf-8")
    assert run(capsys, "validate", str(fleet))[0] == 0
    code, out, err = run(capsys, "poll", str(fleet), "--once", "--json")
    assert code == 0, err
    samples = [json.loads(line) for line in out.splitlines()]
    assert sorted((s["device"], s["online"]) for s in samples) == [("jjr8000-3", True), ("jjr8000-7", True)]
    for starter in two_nodes.values():
        assert starter.control_writes == []


def test_an_empty_range_finds_nobody(two_nodes: dict[int, SimulatedStarter], channel: str,
                                     capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    code, _, err = run(capsys, "scan", f"devicenet://virtual/{channel}?{FAST}", "--macs", "10-11", "--timeout", "0.1")
    assert code == 1 and "no node answered" in err
