"""What a fleet's polls put on each line: each device's poll plan and each line's wire budget (``poll --plan``).

A device's poll reads its status (where the transport can) and its configured points the transport can read;
:func:`poll_points` decides that, for the poller and for the plan alike. The plan itself comes from the
transport (:meth:`Transport.plan <starterbus.core.transport.Transport.plan>`), without opening anything.
"""

from __future__ import annotations

from dataclasses import dataclass

from starterbus.core.device import Device, open_device
from starterbus.core.model import PointDef
from starterbus.core.transport import Capability, PlannedRequest
from starterbus.fleet.config import BusConfig, DeviceConfig, FleetConfig


def poll_points(config: DeviceConfig, device: Device) -> tuple[list[PointDef], bool, set[str]]:
    """(points each poll reads, whether it reads the status, configured keys the transport cannot read)."""
    caps = device.capabilities
    keys = [k for k in config.measurements if Capability.READ_MEASUREMENTS in caps]
    keys += [k for k in config.parameters if Capability.READ_PARAMETERS in caps]
    skipped = set(config.measurements + config.parameters) - set(keys)
    return device.resolve(dict.fromkeys(keys)), Capability.STATUS in caps, skipped


@dataclass(frozen=True, slots=True)
class DevicePlan:
    name: str
    model: str
    period: float
    requests: tuple[PlannedRequest, ...]

    @property
    def registers(self) -> int:
        return sum(r.registers for r in self.requests)

    @property
    def sent(self) -> int:
        """The requests that send something (a value in every cycle's inputs sends nothing of its own)."""
        return sum(1 for r in self.requests if r.frames)

    @property
    def wire_time(self) -> float | None:
        times = [r.wire_time for r in self.requests]
        return None if any(t is None for t in times) else sum(t for t in times if t is not None)

    def as_json(self) -> dict[str, object]:
        return {
            "device": self.name,
            "model": self.model,
            "period": self.period,
            "requests": [r.as_json() for r in self.requests],
            "registers": self.registers,
            "wire_time": self.wire_time,
        }


@dataclass(frozen=True, slots=True)
class BusPlan:
    name: str
    url: str
    devices: tuple[DevicePlan, ...]

    @property
    def wire_time(self) -> float | None:
        """Wire time of one poll of every device (one round), s; None if a transport cannot tell."""
        times = [d.wire_time for d in self.devices]
        return None if any(t is None for t in times) else sum(t for t in times if t is not None)

    @property
    def load(self) -> float | None:
        """The share of the line's time the polls need at the devices' periods (1.0: the line is full)."""
        loads = [None if d.wire_time is None else d.wire_time / d.period for d in self.devices]
        return None if any(x is None for x in loads) else sum(x for x in loads if x is not None)

    @property
    def max_rounds_per_s(self) -> float | None:
        """The physical limit of this plan: rounds per second with the wire never idle."""
        wire = self.wire_time
        return None if not wire else 1.0 / wire

    def as_json(self) -> dict[str, object]:
        return {
            "bus": self.name,
            "url": self.url,
            "devices": [d.as_json() for d in self.devices],
            "wire_time_per_round": self.wire_time,
            "load": self.load,
            "max_rounds_per_s": self.max_rounds_per_s,
        }


def device_plan(config: DeviceConfig) -> DevicePlan:
    device = open_device(config.url, config.model)  # built, not opened: nothing is sent
    points, status, _ = poll_points(config, device)
    requests = tuple(device.transport.plan(points, status))
    return DevicePlan(config.name, config.model, config.period, requests)


def bus_plan(bus: BusConfig) -> BusPlan:
    return BusPlan(bus.name, bus.url, tuple(device_plan(d) for d in bus.devices))


def fleet_plan(config: FleetConfig) -> list[BusPlan]:
    return [bus_plan(bus) for bus in config.buses]
