"""Polling the simulated mixed fleet: every device's values, offline and back, isolation between buses."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from starterbus.cli.main import main
from starterbus.fleet.demo import DemoFleet
from starterbus.fleet.poller import FleetPoller

if TYPE_CHECKING:
    from starterbus.tests.fleet.conftest import Samples


def test_poll_once_json_gives_every_device(demo: DemoFleet, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    fleet_file = tmp_path / "fleet.toml"
    fleet_file.write_text(demo.fleet_toml, encoding="utf-8")
    csv_file = tmp_path / "log.csv"
    assert main(["poll", str(fleet_file), "--once", "--json", "--csv", str(csv_file)]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.strip()]
    by_device = {s["device"]: s for s in lines}
    assert set(by_device) == {"conveyor", "fan", "crusher", "mill", "mixer", "pump-a", "pump-b"}
    for name, sample in by_device.items():
        assert sample["online"], (name, sample["error"])
        assert sample["error"] is None, (name, sample["error"])
        starter = demo.starters[name]
        status = sample["status"]
        expected_state = {"stopped": "ready", "starting": "starting", "running": "running"}[starter.phase.value]
        if name.startswith("pump"):  # DeviceNet assemblies do not report "ready"
            expected_state = "stopped" if expected_state == "ready" else expected_state
        assert status["state"] == expected_state, name
        assert status["fault"] is False
    conveyor = by_device["conveyor"]["values"]
    limit = demo.starters["conveyor"].params["current_limit"]
    assert conveyor["current_limit"] == {"value": limit, "unit": "%", "resolution": 1.0, "raw": limit, "label": None}
    assert conveyor["phase_a_current"]["resolution"] == pytest.approx(0.1)
    crusher = by_device["crusher"]["values"]
    assert crusher["current_limit"]["value"] == pytest.approx(demo.starters["crusher"].params["current_limit"] / 100)
    assert by_device["mill"]["values"]["current_limit"]["value"] == demo.starters["mill"].params["current_limit"]
    assert by_device["mixer"]["unreadable"] == []  # PPO3 polls status only: nothing configured that it cannot read
    assert by_device["pump-a"]["status"]["currents"]["a"]["resolution"] == 1.0
    # monitored over explicit messaging (reads never take control): the input assembly's whole amperes
    assert by_device["pump-a"]["values"]["phase_a_current"]["resolution"] == 1.0
    rows = csv_file.read_text(encoding="utf-8").splitlines()
    assert rows[0].startswith("time,device,bus,model,online,state")
    assert len(rows) == 1 + 7  # wide format: one row per sample, a column per configured point
    header = rows[0].split(",")
    assert "current_limit" in header and "phase_a_current" in header
    first = dict(zip(header, rows[1].split(","), strict=True))
    assert first["time"][:4].isdigit() and first["time"][10] == "T"  # ISO 8601


def test_device_removed_goes_offline_and_comes_back(demo: DemoFleet, samples: Samples) -> None:
    line = next(sim for sim in demo.simulators if 2 in getattr(sim, "starters", {}))
    fan = line.starters[2]  # type: ignore[attr-defined]
    poller = FleetPoller(demo.config, samples).start()
    try:
        samples.wait_for(lambda ss: any(s.device == "fan" and s.online for s in ss))
        del line.starters[2]  # type: ignore[attr-defined]
        mark = samples.mark()
        samples.wait_for(lambda ss: any(s.device == "fan" and not s.online for s in ss[mark:]))
        offline = next(s for s in samples.of("fan", mark) if not s.online)
        assert offline.status is None and offline.values == {}, "an offline device never shows values"
        assert "timeout" in (offline.error or "").lower() or "no answer" in (offline.error or "").lower()
        # its neighbour on the same line and every other bus keep answering meanwhile
        mark = samples.mark()
        samples.wait_for(lambda ss: {s.device for s in ss[mark:] if s.online} >= {"conveyor", "mill", "pump-a"})
        line.starters[2] = fan  # type: ignore[attr-defined]
        mark = samples.mark()
        samples.wait_for(lambda ss: any(s.device == "fan" and s.online for s in ss[mark:]))
    finally:
        line.starters[2] = fan  # type: ignore[attr-defined]
        poller.stop()
    fan_runtime = next(r for r in poller.runtimes() if r.config.name == "fan")
    assert fan_runtime.errors >= 1 and fan_runtime.online
