"""The asyncio API: samples as an async stream, remote commands only as the fleet file allows, guarded."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from starterbus.aio import AsyncDevice, AsyncFleet, RemoteNotAllowed
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.core.status import Command
from starterbus.fleet.config import parse_fleet
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator


def fleet_text(port: str) -> str:
    return f"""
[poll]
period = 0.05

[[bus]]
name = "l1"
url = "modbus-rtu://{port}?timeout=0.3"

  [[bus.device]]
  name = "allowed"
  model = "jjr5000"
  address = 2
  remote = {{ commands = ["start"], write = ["ramp_time"] }}

  [[bus.device]]
  name = "closed"
  model = "jjr5000"
  address = 3
"""


def test_samples_stream_and_remote_commands_are_gated(_audit_log_in_tmp: Path) -> None:
    profile = get_profile("jjr5000")
    starters = {2: SimulatedStarter(profile), 3: SimulatedStarter(profile)}
    sim = ModbusRtuSimulator(starters, pty=True).start()
    try:
        port = sim.client_urls()[2].split("://", 1)[1].split("?", 1)[0]
        config = parse_fleet(fleet_text(port), "f.toml")

        async def scenario() -> None:
            async with AsyncFleet(config) as fleet:
                seen: set[str] = set()
                async for sample in fleet.samples():
                    assert sample.online, sample.error
                    seen.add(sample.device)
                    if seen == {"allowed", "closed"}:
                        break
                outcome = await fleet.remote_command("allowed", Command.START, actor="mqtt:host-1")
                assert outcome.ok and outcome.reached is not None and outcome.reached.starting
                with pytest.raises(RemoteNotAllowed, match="does not allow the command 'stop'"):
                    await fleet.remote_command("allowed", Command.SOFT_STOP, actor="mqtt:host-1")
                with pytest.raises(RemoteNotAllowed, match="does not allow the command 'start'"):
                    await fleet.remote_command("closed", Command.START, actor="mqtt:host-1")
                with pytest.raises(RemoteNotAllowed, match="remote writes of 'current_limit'"):
                    await fleet.remote_write("allowed", {"current_limit": 400}, actor="mqtt:host-1")
                (written,) = await fleet.remote_write("allowed", {"ramp_time": 25}, actor="mqtt:host-1")
                assert written.ok

        asyncio.run(scenario())
        assert starters[2].phase.value == "starting" and starters[3].phase.value == "stopped"
        assert starters[2].params["ramp_time"] == 25 and starters[2].params["current_limit"] == 350
        entries = [json.loads(x) for x in _audit_log_in_tmp.read_text(encoding="utf-8").splitlines()]
        assert [(e["actor"], e.get("command") or e.get("key"), e["result"]) for e in entries] == [
            ("mqtt:host-1", "start", "ok"), ("mqtt:host-1", "ramp_time", "ok"),
        ]  # fmt: skip
    finally:
        sim.close()


def test_async_device_runs_off_the_loop() -> None:
    profile = get_profile("ssd1")
    sim = ModbusRtuSimulator({4: SimulatedStarter(profile)}, pty=True).start()
    try:

        async def scenario() -> None:
            async with AsyncDevice.open_url(sim.client_urls()[4], "ssd1") as device:
                status, values = await asyncio.gather(device.status(), device.read("ramp_time"))
                assert status.ready and values["ramp_time"].unit == "s"
                (outcome,) = await device.write({"ramp_time": 12})
                assert outcome.ok

        asyncio.run(scenario())
    finally:
        sim.close()


def test_a_stream_subscribed_before_the_start_misses_no_sample() -> None:
    """serve subscribes its edge node before the poller starts: what is polled while the other servers start
    (OPC UA takes seconds) still reaches it, the first sample of each device included."""
    profile = get_profile("jjr5000")
    sim = ModbusRtuSimulator({2: SimulatedStarter(profile), 3: SimulatedStarter(profile)}, pty=True).start()
    try:
        port = sim.client_urls()[2].split("://", 1)[1].split("?", 1)[0]
        config = parse_fleet(fleet_text(port), "f.toml")

        async def scenario() -> list[tuple[str, float]]:
            fleet = AsyncFleet(config)
            stream = fleet.subscribe()  # before the poller exists
            seen: list[tuple[str, float]] = []
            async with fleet:
                assert fleet.poller is not None
                while fleet.poller.transactions() < 6:  # a slow start-up: polls go on, nobody reads yet
                    await asyncio.sleep(0.01)
                async for sample in stream:
                    seen.append((sample.device, sample.time))
                    if len(seen) == 4:
                        break
            stream.close()
            return seen

        seen = asyncio.run(scenario())
        assert {device for device, _ in seen[:2]} == {"allowed", "closed"}  # the very first round
        assert [t for _, t in seen] == sorted(t for _, t in seen)
    finally:
        sim.close()
