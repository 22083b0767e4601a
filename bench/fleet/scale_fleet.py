"""The simulated fleet of ``bench/fleet/scale.py``: devices dealt over Modbus RTU lines (ptys) and DeviceNet buses
(virtual CAN), their simulators started, and the fleet file that polls them."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from urllib.parse import parse_qsl, urlencode

from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.core.transport import RunningSimulator
from starterbus.fleet.config import FleetConfig, parse_fleet
from starterbus.transports.devicenet.simulator import DeviceNetSimulator
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator

MODBUS_MODELS = ("jjr5000", "ssd1")
DEVICENET_MODEL = "jjr8000"
MAX_MODBUS_UNITS = 247
MAX_DEVICENET_SLAVES = 62
DEVICENET_MEASUREMENTS = ("phase_a_current",)  # one status parameter: selected once, no settling per read


# -- the fleet --------------------------------------------------------------------------------------------------


@dataclass
class LinePlan:
    name: str
    kind: str  # "modbus" | "devicenet"
    devices: list[tuple[str, str, int]] = field(default_factory=list)  # (name, model, address)

    @property
    def capacity(self) -> int:
        return MAX_MODBUS_UNITS if self.kind == "modbus" else MAX_DEVICENET_SLAVES


def plan_lines(n: int, modbus_lines: int, devicenet_lines: int) -> list[LinePlan]:
    """Deal ``n`` devices round-robin over the lines (Modbus and DeviceNet alternating); a full line is skipped."""
    lines: list[LinePlan] = []
    for i in range(max(modbus_lines, devicenet_lines)):
        if i < modbus_lines:
            lines.append(LinePlan(f"rtu-{i + 1}", "modbus"))
        if i < devicenet_lines:
            lines.append(LinePlan(f"dnet-{i + 1}", "devicenet"))
    capacity = sum(line.capacity for line in lines)
    if n > capacity:
        raise SystemExit(f"{n} devices do not fit on {len(lines)} lines (at most {capacity})")
    turn = 0
    for _ in range(n):
        while len(lines[turn % len(lines)].devices) >= lines[turn % len(lines)].capacity:
            turn += 1
        line = lines[turn % len(lines)]
        turn += 1
        address = len(line.devices) + 1
        model = MODBUS_MODELS[len(line.devices) % 2] if line.kind == "modbus" else DEVICENET_MODEL
        line.devices.append((f"{line.name}-{address:03d}", model, address))
    return [line for line in lines if line.devices]


def _bus_url(url: str, drop: str) -> str:
    base, _, query = url.partition("?")
    params = dict(parse_qsl(query))
    params.pop(drop, None)
    return f"{base}?{urlencode(params)}" if params else base


@dataclass
class Fleet:
    config: FleetConfig
    lines: list[LinePlan]
    simulators: list[RunningSimulator]

    def close(self) -> None:
        for sim in reversed(self.simulators):
            sim.close()


def start_fleet(lines: list[LinePlan], baudrate: int, period: float, devicenet_period: float) -> Fleet:
    """Start one simulator per line and build the fleet file that reaches them."""
    sims: list[RunningSimulator] = []
    parts = [f"[poll]\nperiod = {period}\nmax_backoff = 2.0\n"]
    try:
        for index, line in enumerate(lines):
            if line.kind == "modbus":
                starters = {address: SimulatedStarter(get_profile(model)) for _, model, address in line.devices}
                rtu = ModbusRtuSimulator(starters, pty=True, baudrate=baudrate).start()
                sims.append(rtu)
                url = _bus_url(rtu.client_urls()[line.devices[0][2]], "unit")
            else:
                channel = f"bench-fleet-{os.getpid()}-{index}"
                dnet = DeviceNetSimulator(("virtual", channel), dup_mac_wait=0.05)
                for _, model, address in line.devices:
                    dnet.add_node(SimulatedStarter(get_profile(model)), address)
                sims.append(dnet.start())
                if not dnet.wait_online(10.0):
                    raise RuntimeError(f"{line.name}: simulated DeviceNet nodes did not come on line")
                url = f"devicenet://virtual/{channel}?master_mac=0&assemblies=extended&dup_mac_wait=0.05"
            parts.append(f'[[bus]]\nname = "{line.name}"\nurl = "{url}"\n')
            for name, model, address in line.devices:
                extra = ""
                if line.kind == "devicenet":
                    extra = f"\n  measurements = {json.dumps(list(DEVICENET_MEASUREMENTS))}"
                    if devicenet_period != period:
                        extra += f"\n  period = {devicenet_period}"
                parts.append(
                    f'  [[bus.device]]\n  name = "{name}"\n  model = "{model}"\n  address = {address}{extra}\n'
                )
        config = parse_fleet("\n".join(parts), "<bench fleet>")
    except BaseException:
        for sim in reversed(sims):
            sim.close()
        raise
    return Fleet(config, lines, sims)
