"""One simulated JJR8000 behind three protocol front ends: the paths agree; two different starters do not."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator

import pytest

from starterbus.cli.main import main
from starterbus.core.registry import get_profile
from starterbus.core.simulator import ManualClock, SimulatedStarter
from starterbus.fleet.crosscheck import crosscheck

CHANNEL = f"crosscheck-{os.getpid()}"


@pytest.fixture(scope="module")
def three_paths() -> Iterator[tuple[list[str], SimulatedStarter, SimulatedStarter]]:
    from starterbus.transports.devicenet.simulator import DeviceNetSimulator
    from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator
    from starterbus.transports.profibus_pkw.simulator import ProfibusGatewaySimulator

    profile = get_profile("jjr8000")
    clock = ManualClock()  # the motor changes only when the test says so: every path sees one state
    starter = SimulatedStarter(profile, clock, values={"ramp_time": 2})
    other = SimulatedStarter(profile, values={"current_limit": 420})
    rtu = ModbusRtuSimulator({2: starter, 3: other}, pty=True).start()
    gateway = ProfibusGatewaySimulator(starter, ppo=1).start()
    dnet = DeviceNetSimulator(("virtual", CHANNEL), dup_mac_wait=0.05)
    dnet.add_node(starter, 5)
    dnet.start()
    urls = [
        rtu.client_urls()[2],
        gateway.client_urls()[1],
        f"devicenet://virtual/{CHANNEL}?mac=5&assemblies=extended&dup_mac_wait=0.05",
        rtu.client_urls()[3],
    ]
    try:
        yield urls, starter, other
    finally:
        dnet.close()
        gateway.close()
        rtu.close()


def test_three_protocols_agree_on_one_starter(
    three_paths: tuple[list[str], SimulatedStarter, SimulatedStarter],
) -> None:
    urls, starter, _ = three_paths
    starter.start()
    starter.clock.advance(10.0)  # type: ignore[attr-defined]  # steady running, current 0.8 x rated
    report = crosscheck(urls[:3], "jjr8000", ["m1", "m2", "m3", "m4", "p7", "p3"])
    assert report.ok, report.as_json()
    rows = {r.what: r for r in report.rows}
    assert rows["current_limit"].agree is True  # Modbus and PPO1 read it; DeviceNet cannot
    assert rows["current_limit"].readings[2] is None
    assert rows["status.running"].agree is True or rows["status.starting"].agree is True
    assert rows["status.current_a"].agree is True  # 0.1 A paths against the whole-ampere DeviceNet assembly
    assert all(p.error is None for p in report.paths)


def test_skewed_device_disagrees(
    three_paths: tuple[list[str], SimulatedStarter, SimulatedStarter], capsys: pytest.CaptureFixture[str]
) -> None:
    urls, _, _ = three_paths
    code = main(["crosscheck", "--model", "jjr8000", urls[0], urls[3], "--keys", "p7", "p3", "--json"])
    assert code == 1
    report = json.loads(capsys.readouterr().out)
    assert report["ok"] is False
    rows = {r["what"]: r for r in report["rows"]}
    assert rows["current_limit"]["agree"] is False
    assert rows["current_limit"]["readings"] == ["3.50 x In", "4.20 x In"]
