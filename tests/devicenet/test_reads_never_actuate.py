"""Issue 25's sequence in one process: a JJR8000 started over Modbus RTU (as the PLC or the keypad would), then
read over DeviceNet and Profibus with every read-only operation; the motor runs on, and the DeviceNet slave
never saw a poll command (output data) from the reading master."""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator

import pytest

from starterbus.core.device import open_device
from starterbus.core.errors import UnsupportedOperationError
from starterbus.core.profile import Profile
from starterbus.core.simulator import ManualClock, Phase, SimulatedStarter
from starterbus.core.status import Command, MotorState
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.crosscheck import crosscheck
from starterbus.fleet.poller import FleetPoller
from starterbus.fleet.sample import Sample
from starterbus.ops.backup import take_backup
from starterbus.transports.devicenet.codec.ids import poll_command_id
from starterbus.transports.devicenet.simulator import DeviceNetSlaveSimulator
from starterbus.transports.devicenet.transport import ControlConflictError
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator
from starterbus.transports.profibus_pkw.simulator import ProfibusGatewaySimulator

FAST = "dup_mac_wait=0.05&timeout=0.5"


@pytest.fixture
def running(jjr8000: Profile, channel: str) -> Iterator[tuple[SimulatedStarter, str, str, str]]:
    """One starter behind Modbus RTU, DeviceNet and a Profibus PPO1 gateway, started over Modbus and running."""
    starter = SimulatedStarter(jjr8000, ManualClock(0.0))
    with (
        ModbusRtuSimulator({2: starter}, pty=True) as rtu,
        DeviceNetSlaveSimulator(starter, ("virtual", channel), 5, dup_mac_wait=0.05),
        ProfibusGatewaySimulator(starter, ppo=1, cycle=0.002) as gateway,
    ):
        modbus = rtu.client_urls()[2] + "&timeout=0.5"
        with open_device(modbus, jjr8000) as device:
            assert device.start().ok
        starter.clock.advance(100.0)  # type: ignore[attr-defined]
        assert starter.phase is Phase.RUNNING and starter.current() > 0
        yield starter, modbus, f"devicenet://virtual/{channel}?mac=5&{FAST}", gateway.client_urls()[1] + "&timeout=2"


def test_every_read_over_devicenet_and_profibus_leaves_the_motor_running(
    running: tuple[SimulatedStarter, str, str, str], sniffer: object, jjr8000: Profile
) -> None:
    starter, modbus, devicenet, profibus = running
    mark = starter.control_writes_total
    reads: dict[str, Callable[[], object]] = {}
    phase_a = jjr8000.point("phase_a_current")
    for name, url in (("devicenet", devicenet), ("profibus", profibus)):
        reads[f"{name} status"] = functools.partial(_status, url, jjr8000)
        reads[f"{name} read"] = functools.partial(_with, url, jjr8000, lambda d: d.read(phase_a.key))
        reads[f"{name} backup"] = functools.partial(_with, url, jjr8000, take_backup)
        reads[f"{name} poll"] = functools.partial(_with, url, jjr8000, lambda d: d.transport.poll([phase_a], True))
    reads["devicenet identify"] = lambda: _with(devicenet, jjr8000, lambda d: d.transport.identify())
    reads["crosscheck"] = lambda: crosscheck([modbus, devicenet, profibus], jjr8000)
    for what, read in reads.items():
        try:
            read()
        except UnsupportedOperationError:
            assert what == "devicenet backup"  # no parameter access over DeviceNet: refused before anything is sent
        assert starter.phase is Phase.RUNNING, f"{what} changed the run state"
        assert starter.control_writes_since(mark) == [], f"{what} sent {starter.control_writes_since(mark)}"
    frames = sniffer.texts()  # type: ignore[attr-defined]
    polls = [t for t in frames if t.startswith(f"{poll_command_id(5):03X}#")]
    assert polls == [], f"the reading master sent output data: {polls[:3]}"


def test_a_fleet_poll_over_devicenet_leaves_the_motor_running(
    running: tuple[SimulatedStarter, str, str, str], channel: str
) -> None:
    starter, _, _, _ = running
    fleet = parse_fleet(
        f'[[bus]]\nname = "dn"\nurl = "devicenet://virtual/{channel}?{FAST}"\n'
        'device = [{ name = "pump", model = "jjr8000", address = 5 }]\n',
        "<test>",
    )
    mark = starter.control_writes_total
    samples: list[Sample] = []
    poller = FleetPoller(fleet, samples.append, rounds=2).start()
    poller.join(10.0)
    assert not poller.running and poller.failure is None
    assert samples and all(s.error is None for s in samples), samples[0].error
    assert all(s.online and s.status is not None for s in samples), samples
    assert all(s.status.state is MotorState.RUNNING for s in samples if s.status is not None)
    assert starter.phase is Phase.RUNNING and starter.control_writes_since(mark) == []


def test_control_open_and_a_fault_reset_refuse_to_stop_a_motor_run_from_elsewhere(
    running: tuple[SimulatedStarter, str, str, str], jjr8000: Profile
) -> None:
    starter, _, devicenet, _ = running
    mark = starter.control_writes_total
    with pytest.raises(ControlConflictError, match="running under another control"):
        open_device(devicenet + "&control=open", jjr8000).open()
    with (
        open_device(devicenet, jjr8000) as device,
        pytest.raises(ControlConflictError, match="a fault reset would take control"),
    ):
        device.transport.send_command(Command.FAULT_RESET)
    assert starter.phase is Phase.RUNNING and starter.control_writes_since(mark) == []


def _status(url: str, profile: Profile) -> MotorState:
    with open_device(url, profile) as device:
        state = device.status().state
    assert state is MotorState.RUNNING, url
    return state


def _with(url: str, profile: Profile, call: Callable[..., object]) -> object:
    with open_device(url, profile) as device:
        return call(device)
