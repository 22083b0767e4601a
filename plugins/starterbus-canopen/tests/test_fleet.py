"""A fleet file polls two canopen devices on one bus next to a modbus-rtu device: all online, all read."""

from __future__ import annotations

from starterbus_canopen.simulator import CanopenSimulator

from starterbus.core import ManualClock, SimulatedStarter, get_profile
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.poller import FleetPoller, Sample
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator


def test_a_fleet_polls_canopen_next_to_modbus_rtu(channel: str) -> None:
    canopen_starter = SimulatedStarter(get_profile("example_canopen_starter"), ManualClock(0.0))
    second_starter = SimulatedStarter(get_profile("example_canopen_starter"), ManualClock(0.0))
    second_starter.params["current_limit"] = 390
    modbus_starter = SimulatedStarter(get_profile("jjr5000"), ManualClock(0.0))
    canopen_starter.params["current_limit"] = 420
    with (
        CanopenSimulator(("virtual", channel), heartbeat_ms=0) as can_sim,
        ModbusRtuSimulator({2: modbus_starter}, pty=True) as rtu_sim,
    ):
        can_sim.add_node(canopen_starter, 5)
        can_sim.add_node(second_starter, 6)
        port = rtu_sim.client_urls()[2].split("://", 1)[1].split("?", 1)[0]
        config = parse_fleet(
            f"""
[poll]
period = 0.05

[[bus]]
name = "can"
url = "canopen://virtual/{channel}?heartbeat=50"

  [[bus.device]]
  name = "fan"
  model = "example_canopen_starter"
  address = 5
  measurements = ["phase_a_current"]
  parameters = ["current_limit"]

  [[bus.device]]
  name = "fan2"
  model = "example_canopen_starter"
  address = 6
  parameters = ["current_limit"]

[[bus]]
name = "rtu"
url = "modbus-rtu://{port}?timeout=0.3"

  [[bus.device]]
  name = "pump"
  model = "jjr5000"
  address = 2
  parameters = ["current_limit"]
""",
            "fleet.toml",
        )
        samples: list[Sample] = []
        poller = FleetPoller(config, samples.append, rounds=1).start()
        poller.join(30)
        assert not poller.running
    by_device = {s.device: s for s in samples}
    assert set(by_device) == {"fan", "fan2", "pump"}
    for sample in samples:
        assert sample.online and sample.error is None, (sample.device, sample.error)
        assert sample.status is not None and sample.status.state.value == "ready"
    assert by_device["fan"].values["current_limit"].raw == 420
    assert by_device["fan2"].values["current_limit"].raw == 390
    assert by_device["pump"].values["current_limit"].raw == 350
