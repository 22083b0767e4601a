"""Northbound commands (Sparkplug DCMDs, OPC UA methods) go through the same guarded path: a starter controlled
from elsewhere refuses them before any frame, and remote callers have no override."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from starterbus.aio import AsyncFleet
from starterbus.core.errors import ControlSourceError, ValidationError
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.core.status import Command
from starterbus.fleet.config import parse_fleet
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

FLEET = """
[poll]
period = 0.05

[[bus]]
name = "l1"
url = "modbus-rtu://{port}?timeout=0.3"

  [[bus.device]]
  name = "local"
  model = "jjr5000"
  address = 2
  remote = {{ commands = ["start", "stop", "reset"] }}
"""


def test_a_remote_command_to_a_starter_on_keypad_control_is_refused(_audit_log_in_tmp: Path) -> None:
    starter = SimulatedStarter(get_profile("jjr5000"), values={"control_source": 1})  # keypad
    sim = ModbusRtuSimulator({2: starter}, pty=True).start()
    try:
        port = sim.client_urls()[2].split("://", 1)[1].split("?", 1)[0]
        config = parse_fleet(FLEET.format(port=port), "f.toml")

        async def scenario() -> None:
            async with AsyncFleet(config) as fleet:
                for command in (Command.START, Command.SOFT_STOP, Command.FAULT_RESET):
                    with pytest.raises(ControlSourceError, match=r"control_source \(0x013E\) is keypad") as info:
                        await fleet.remote_command("local", command, actor="mqtt:host-1")
                    assert isinstance(info.value, ValidationError)  # serve: a refused DCMD, "nothing was sent"

        asyncio.run(scenario())
        assert starter.control_writes == [] and starter.phase.value == "stopped"
        entries = [json.loads(x) for x in _audit_log_in_tmp.read_text(encoding="utf-8").splitlines()]
        assert [(e["actor"], e["command"]) for e in entries] == [
            ("mqtt:host-1", "start"), ("mqtt:host-1", "stop"), ("mqtt:host-1", "reset"),
        ]  # fmt: skip
        assert all(str(e["result"]).startswith("refused: ") for e in entries)
    finally:
        sim.close()


def test_opc_ua_reports_bad_invalid_state() -> None:
    from asyncua import ua

    from starterbus.opcua.refusals import status_code

    error = ControlSourceError("start X: refused, the starter is controlled from elsewhere", "keypad")
    assert status_code(error, write=False) == ua.StatusCodes.BadInvalidState
