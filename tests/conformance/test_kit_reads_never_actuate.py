"""The kit's read-never-actuates check fails on deliberately broken transports, naming the operation and the
control word: Modbus RTU transports that write the control word on open, while reading the status, or while
previewing a command, and one that writes a parameter while identifying the device."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from starterbus.core.device import open_device
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.simulator import ManualClock, Phase, SimulatedStarter
from starterbus.core.status import CW_BUS_CONTROL, Command, Status
from starterbus.core.transport import Transport
from starterbus.core.url import DeviceUrl
from starterbus.testing import TransportConformance
from starterbus.transports.modbus.plugin.rtu import ModbusRtuPlugin
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator
from starterbus.transports.modbus.transport.rtu import ModbusRtuTransport


class Kit(TransportConformance):
    transport = "modbus-rtu"
    model = "jjr5000"


def control_register(transport: ModbusRtuTransport) -> int:
    point = transport.profile.role("control_word")
    assert point is not None
    return int(point.address_for("modbus-rtu"))


class WritesOnOpen(ModbusRtuTransport):
    """ "Synchronises" the control word on open: its own idea of it (0x0000, a soft stop level)."""

    def _open(self) -> None:
        super()._open()
        self.write_register(control_register(self), self.control.word)


class TakesControlToRead(ModbusRtuTransport):
    """Sets the bus-control bit before each status read."""

    def _read_status(self) -> Status:
        self.write_register(control_register(self), CW_BUS_CONTROL)
        return super()._read_status()


class PreviewSends(ModbusRtuTransport):
    """A dry run that sends what it previews."""

    def _preview_command(self, command: Command) -> list[str]:
        frames = super()._preview_command(command)
        for request in self._control_requests(command):
            self.execute(request)
        return frames


class IdentifyWrites(ModbusRtuTransport):
    """Identifies the device by writing a parameter (then says it cannot identify)."""

    def _identify(self) -> dict[str, object]:
        point = self.profile.point("motor_rated_current")
        self.write_register(int(point.address_for("modbus-rtu")), point.raw_max)
        return super()._identify()


@pytest.fixture
def profile() -> Profile:
    return get_profile("jjr5000")


@pytest.fixture
def starter(profile: Profile) -> SimulatedStarter:
    return SimulatedStarter(profile, ManualClock(0.0), load=0.5)


@pytest.fixture
def url(starter: SimulatedStarter) -> Iterator[str]:
    with ModbusRtuSimulator({2: starter}, pty=True) as sim:
        yield sim.client_urls()[2] + "&timeout=0.5"


def broken(monkeypatch: pytest.MonkeyPatch, cls: type[ModbusRtuTransport]) -> None:
    """Make the registered modbus-rtu plugin open ``cls`` (the kit, the crosscheck and the fleet all use it)."""

    def open_broken(self: ModbusRtuPlugin, url: DeviceUrl, profile: Profile) -> Transport:
        return cls(url, profile)

    monkeypatch.setattr(ModbusRtuPlugin, "open", open_broken)


@pytest.mark.parametrize(
    ("cls", "expected"),
    [
        (
            WritesOnOpen,
            r"seen during open: control word 0x0008 \(soft stop, bus control; one-off from Modbus FC06 unit 2\)",
        ),
        (TakesControlToRead, r"seen during status: control word 0x0008 \(soft stop, bus control; one-off"),
        (PreviewSends, r"seen during previews \(dry run of every write and command\): control word 0x0009 \(start"),
        (IdentifyWrites, r"changed parameters: motor_rated_current"),
    ],
)
def test_the_check_fails_on_a_transport_that_actuates_while_reading(
    monkeypatch: pytest.MonkeyPatch,
    url: str,
    profile: Profile,
    starter: SimulatedStarter,
    cls: type[ModbusRtuTransport],
    expected: str,
) -> None:
    broken(monkeypatch, cls)
    assert isinstance(open_device(url, profile).transport, cls)
    with pytest.raises(AssertionError, match=expected):
        Kit().test_reads_never_actuate(url, profile, starter)


def test_a_stopped_motor_is_a_failure_too(url: str, profile: Profile, starter: SimulatedStarter) -> None:
    """A starter stopped during the reads without any control output recorded (here: its keypad, from a status
    read of the sound transport) fails on the motor's state, naming the states."""

    class StopsOnStatus(TransportConformance):
        transport = "modbus-rtu"

    original = starter.status_word

    def status_word() -> int:
        starter.soft_stop("stopped behind the kit's back")
        return original()

    starter.status_word = status_word  # type: ignore[method-assign]
    with pytest.raises(AssertionError, match="changed the motor's state: running -> stopp(ing|ed)"):
        StopsOnStatus().test_reads_never_actuate(url, profile, starter)
    assert starter.phase in (Phase.STOPPING, Phase.STOPPED) and starter.control_writes == []
