"""The profibus-pkw transport through the in-process simulated slave: URLs, capabilities, every operation."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest

from starterbus.core.device import Device, open_device
from starterbus.core.errors import (
    ConfigurationError,
    DecodeError,
    RemoteDeviceError,
    UnsupportedOperationError,
    ValidationError,
)
from starterbus.core.model import Kind, PointDef
from starterbus.core.profile import Profile, load_profile_text
from starterbus.core.simulator import ManualClock, Phase, SimulatedStarter
from starterbus.core.status import Command, MotorState
from starterbus.core.transport import Capability
from starterbus.core.url import DeviceUrl
from starterbus.transports.profibus_pkw.codec.codes import Ppo, ResponseCode
from starterbus.transports.profibus_pkw.driver.channels import Channel, SimChannel, Snapshot, attach_slave, get_slave
from starterbus.transports.profibus_pkw.master.handshake import PkwError
from starterbus.transports.profibus_pkw.plugin import PLUGIN
from starterbus.transports.profibus_pkw.slave import SimulatedDpSlave
from starterbus.transports.profibus_pkw.transport import ProfibusPkwTransport
from starterbus.transports.profibus_pkw.url import LinkSettings


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock(1000.0)


def phase(starter: SimulatedStarter) -> Phase:
    """The motor state now (a call, so that type checkers do not narrow it between commands)."""
    return starter.phase


def attached(name: str, profile: Profile, clock: ManualClock, ppo: int = 1, **kw: object) -> SimulatedStarter:
    starter = SimulatedStarter(profile, clock, **kw)  # type: ignore[arg-type]
    attach_slave(name, starter, ppo)
    return starter


@pytest.fixture(params=["0", "0.002"], ids=["on-demand", "cycling"])
def cycle(request: pytest.FixtureRequest) -> str:
    return str(request.param)


# -- URLs -------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("url", "error", "match"),
    [
        ("profibus-pkw://x?ppo=1", ConfigurationError, "choose a channel"),
        ("profibus-pkw+serial://x", ConfigurationError, "choose a channel"),
        ("profibus-pkw+sim://?ppo=2", ConfigurationError, "ppo: 2 is not 1"),
        ("profibus-pkw+sim://?ppo=x", ConfigurationError, "not an integer"),
        ("profibus-pkw+sim://?baud=9600", ConfigurationError, "unknown URL parameter"),
        ("profibus-pkw+sim://?out=0", ConfigurationError, "unknown URL parameter"),
        ("profibus-pkw+gateway://?ppo=1", ConfigurationError, "HOST:PORT"),
        ("profibus-pkw+gateway://h:502?latency=1", ConfigurationError, "unknown URL parameter"),
        ("profibus-pkw+gateway://h:502?in_fc=16", ConfigurationError, "in_fc"),
        ("profibus-pkw+gateway://h:502?out=70000", ConfigurationError, "out"),
        ("profibus-pkw+sim://?station=0", ConfigurationError, "outside JJR8000's range 1..127"),
        ("profibus-pkw+sim://?cycle=-1", ConfigurationError, "cycle"),
        ("profibus-pkw+sim://?max_cycles=1", ConfigurationError, "max_cycles"),
    ],
)
def test_bad_urls_are_configuration_errors(url: str, error: type[Exception], match: str, jjr8000: Profile) -> None:
    with pytest.raises(error, match=match):
        PLUGIN.open(DeviceUrl.parse(url), jjr8000)


def test_url_settings(jjr5000: Profile) -> None:
    s = LinkSettings.from_url(
        DeviceUrl.parse("profibus-pkw+gateway://10.0.0.5:1502?ppo=3&out=8&in=16&unit=7&cycle=0.02&in_fc=4"), jjr5000
    )
    assert (s.variant, s.ppo, s.host, s.port, s.out, s.inp, s.unit, s.in_fc) == (
        "gateway", Ppo.PPO3, "10.0.0.5", 1502, 8, 16, 7, 4,
    )  # fmt: skip
    assert s.cycle == 0.02 and s.pulse == 0.05 and s.hold == 3
    d = LinkSettings.from_url(DeviceUrl.parse("profibus-pkw+gateway://gw"), jjr5000)
    assert (d.port, d.ppo, d.out, d.inp, d.unit, d.in_fc) == (502, Ppo.PPO1, 0, 0, 1, 3)
    sim = LinkSettings.from_url(
        DeviceUrl.parse("profibus-pkw+sim://Line-1?latency=2&timeout=0.5&max_cycles=9"), jjr5000
    )
    assert (sim.name, sim.latency, sim.limits.timeout, sim.limits.max_cycles, sim.pulse) == ("line-1", 2, 0.5, 9, 0.0)


def test_a_model_without_the_ppo_type_or_without_profibus(jjr5000: Profile, ssd1: Profile) -> None:
    text = Path(jjr5000.source).read_text(encoding="utf-8").replace("ppo = [1, 3]", "ppo = [1]")
    only1 = load_profile_text(text, "only1.toml")
    with pytest.raises(ConfigurationError, match=r"ppo: 3: .* does not offer PPO3 .*\(it offers: ppo=1 \(PPO1\)\)"):
        PLUGIN.open(DeviceUrl.parse("profibus-pkw+sim://?ppo=3"), only1)
    with pytest.raises(UnsupportedOperationError, match="no profibus-pkw interface"):
        open_device("profibus-pkw+sim://?ppo=1", ssd1)


# -- named in-process slaves --------------------------------------------------------------------------------


def test_named_slaves(jjr8000: Profile, jjr5000: Profile, clock: ManualClock) -> None:
    starter = attached("press-7", jjr8000, clock)
    with open_device("profibus-pkw+sim://press-7?ppo=1&cycle=0", jjr8000) as dev:
        starter.params["ramp_time"] = 33
        assert dev.read_value("ramp_time").value == 33
    assert get_slave("PRESS-7").starter is starter  # names are case-insensitive (URL hosts are)
    with pytest.raises(ConfigurationError, match="already attached"):
        attach_slave("press-7", starter)
    with pytest.raises(ConfigurationError, match="not a slave name"):
        attach_slave("a b", starter)
    with pytest.raises(ConfigurationError, match="configured for PPO1"):
        open_device("profibus-pkw+sim://press-7?ppo=3", jjr8000).open()
    with pytest.raises(ConfigurationError, match="is a JJR8000, not a JJR5000"):
        open_device("profibus-pkw+sim://press-7?ppo=1", jjr5000).open()
    with pytest.raises(ConfigurationError, match="attached: press-7"):
        open_device("profibus-pkw+sim://nobody?ppo=1", jjr8000).open()


def test_a_ready_slave_can_be_attached(jjr5000: Profile) -> None:
    slave = SimulatedDpSlave(SimulatedStarter(jjr5000), Ppo.PPO3, latency=1)
    assert attach_slave("m3", slave) is slave and slave.name == "m3"
    with open_device("profibus-pkw+sim://m3?ppo=3&cycle=0", jjr5000) as dev:
        assert dev.status().ready


# -- capabilities -------------------------------------------------------------------------------------------


def test_capabilities_per_ppo(jjr5000: Profile) -> None:
    t1 = PLUGIN.open(DeviceUrl.parse("profibus-pkw+sim://?ppo=1"), jjr5000)
    t3 = PLUGIN.open(DeviceUrl.parse("profibus-pkw+sim://?ppo=3"), jjr5000)
    assert t1.capabilities == frozenset(Capability)
    assert t3.capabilities == {Capability.STATUS, Capability.COMMANDS}
    assert PLUGIN.capabilities == frozenset(Capability)


@pytest.mark.parametrize("model", ["jjr5000", "jjr8000"])
def test_ppo3_refuses_parameters_in_the_device_and_in_the_transport(model: str, profiles: dict[str, Profile]) -> None:
    profile = profiles[model]
    with open_device("profibus-pkw+sim://?ppo=3&cycle=0", profile) as dev:
        # through the Device as through the transport: the plugin's reason, not only what it offers
        with pytest.raises(UnsupportedOperationError, match="cannot read parameters.*PPO3 carries no PKW"):
            dev.read("current_limit")
        with pytest.raises(UnsupportedOperationError, match="cannot read measurements.*PPO3 carries no PKW"):
            dev.read("phase_b_current")
        with pytest.raises(UnsupportedOperationError, match="cannot write parameters.*PPO3 carries no PKW"):
            dev.write("ramp_time", 20)
        transport = dev.transport
        point = profile.point("ramp_time")
        for call in (
            lambda: transport.read_points([point]),
            lambda: transport.write_parameter(point, 20),
            lambda: transport.preview_write(point, 20),
        ):
            with pytest.raises(UnsupportedOperationError, match="PPO3 carries no PKW"):
                call()
        dev.start()  # status and commands work
        assert dev.status().starting


def test_points_without_a_usable_profibus_address(jjr5000: Profile) -> None:
    transport = PLUGIN.open(DeviceUrl.parse("profibus-pkw+sim://?cycle=0"), jjr5000)
    nowhere = PointDef("extra", Kind.PARAMETER, "0x0199", "", "extra", 0, 1, addresses={"modbus-rtu": 0x199})
    too_far = PointDef("far", Kind.PARAMETER, "0x0299", "", "far", 0, 1, addresses={"profibus-pkw": 0x199})
    with transport:
        with pytest.raises(UnsupportedOperationError, match="no Profibus"):
            transport.read_points([nowhere])
        with pytest.raises(ConfigurationError, match="does not fit INDL"):
            transport.read_points([too_far])
    with pytest.raises(UnsupportedOperationError, match="read-only"):
        transport.preview_write(jjr5000.point("phase_a_current"), 1)


# -- operations ---------------------------------------------------------------------------------------------


@pytest.fixture
def dev8(jjr8000: Profile, clock: ManualClock, cycle: str) -> Iterator[tuple[Device, SimulatedStarter]]:
    starter = attached("j8", jjr8000, clock, load=0.5)
    with open_device(f"profibus-pkw+sim://j8?ppo=1&cycle={cycle}&timeout=1", jjr8000) as dev:
        yield dev, starter


def test_read_parameters_and_measurements(dev8: tuple[Device, SimulatedStarter]) -> None:
    dev, starter = dev8
    values = dev.read("ramp_time", "p7", "m1", "phase_a_current")
    assert values["ramp_time"].value == 12 and values["current_limit"].value == 3.5
    assert values["status_word"].raw == starter.status_word()
    assert values["phase_a_current"].resolution == 0.1 and values["phase_a_current"].source == "profibus-pkw"


def test_write_then_read_back(dev8: tuple[Device, SimulatedStarter]) -> None:
    dev, starter = dev8
    written = dev.write("current_limit", 4.2)
    assert written.read_back is not None and written.read_back.raw == 420 and starter.params["current_limit"] == 420
    assert dev.read_value("p7").value == 4.2
    with pytest.raises(ValidationError):
        dev.write("current_limit", 5.5)  # refused before anything is sent
    assert starter.params["current_limit"] == 420


def test_jjr8000_refuses_while_running_with_error_3(dev8: tuple[Device, SimulatedStarter], clock: ManualClock) -> None:
    dev, starter = dev8
    dev.start()
    clock.advance(60)
    assert phase(starter) is Phase.RUNNING
    with pytest.raises(PkwError) as info:  # the device's own refusal: past the guard's state rule
        dev.send_write(*dev.validate_write("current_limit", 4.0))
    error = info.value
    assert isinstance(error, RemoteDeviceError) and error.response is ResponseCode.CANNOT_EXECUTE
    assert (error.code, error.meaning) == (3, "cannot modify while running")
    assert error.data == bytes.fromhex("03 07 00 03")
    assert starter.params["current_limit"] == 350
    dev.write("motor_overload_protection", 0)  # not locked while running


def test_jjr5000_write_lock_is_error_4(jjr5000: Profile, clock: ManualClock, cycle: str) -> None:
    starter = attached("j5", jjr5000, clock, values={"parameter_modify": 0})
    with open_device(f"profibus-pkw+sim://j5?cycle={cycle}", jjr5000) as dev:
        with pytest.raises(PkwError) as info:
            dev.send_write(*dev.validate_write("current_limit", 380))
        assert info.value.code == 4 and "parameter modification forbidden" in info.value.meaning
        dev.write("parameter_modify", 1)
        dev.write("current_limit", 380)
    assert starter.params["current_limit"] == 380


def test_status_and_commands(dev8: tuple[Device, SimulatedStarter], clock: ManualClock) -> None:
    dev, starter = dev8
    status = dev.status()
    assert status.state is MotorState.READY and status.mains_voltage is None
    assert status.raw["status_word"] == starter.status_word() and status.raw["act"] == 0
    dev.start()
    clock.advance(1)
    status = dev.status()
    assert status.state is MotorState.STARTING and status.bus_control
    assert status.currents["a"].resolution == 0.1
    assert status.currents["a"].value == pytest.approx(round(starter.current(), 1))
    clock.advance(60)
    dev.stop()
    assert phase(starter) is Phase.STOPPING
    starter.inject_fault(6)
    status = dev.status()
    assert status.fault and status.fault_code == 6 and status.fault_text == "motor overload"
    dev.reset()
    assert phase(starter) is Phase.STOPPED and not dev.status().fault
    dev.command(Command.RELEASE_BUS_CONTROL)
    assert not starter.control_word & 0x0008


def test_jjr5000_status_has_the_mains_bit_and_its_fault_table(jjr5000: Profile, clock: ManualClock) -> None:
    starter = attached("j5s", jjr5000, clock, ppo=3)
    starter.inject_fault(5)
    with open_device("profibus-pkw+sim://j5s?ppo=3&cycle=0", jjr5000) as dev:
        status = dev.status()
    assert status.mains_voltage is True and status.fault_text == "mains phase loss"


def test_previews_are_the_exact_output_telegrams(jjr8000: Profile) -> None:
    dev = open_device("profibus-pkw+sim://?ppo=1", jjr8000)
    t = dev.transport
    # not open: a new session's write, its start chain first (fence reads of p8, p9, p10), the control word in force
    # left as it is (a session adopts it)
    chain = [f"{text} -- -- -- --" for indl in (8, 9, 10) for text in ("00 00 00 00", f"01 {indl:02X} 00 00")]
    write = ["00 00 00 00 -- -- -- --", "02 07 01 5E -- -- -- --"]
    assert t.preview_write(jjr8000.point("p7"), 350) == chain + write
    assert t.preview_command(Command.START) == ["00 00 00 00 00 09 00 00"]
    assert t.preview_command(Command.FAULT_RESET) == ["00 00 00 00 00 0C 00 00", "00 00 00 00 00 08 00 00"]
    p3 = open_device("profibus-pkw+sim://?ppo=3", jjr8000).transport
    assert p3.preview_command(Command.SOFT_STOP) == ["00 08 00 00"]


def test_an_open_links_preview_is_what_its_session_sends_next(jjr8000: Profile) -> None:
    """Open, the preview follows the session: the start chain until it is done, then the clear and the task, with
    the control word the link writes (none while it is passive on PZD: ``-- --``, the word in force kept)."""
    with open_device("profibus-pkw+sim://?ppo=1", jjr8000) as dev:
        t = dev.transport
        assert len(t.preview_write(jjr8000.point("p7"), 350)) == 8
        assert [p.frames for p in t.plan([jjr8000.point("p3")], True)] == [0, 2, 2, 2, 2]
        dev.read("p3")
        assert t.preview_write(jjr8000.point("p7"), 350) == ["00 00 00 00 -- -- -- --", "02 07 01 5E -- -- -- --"]
        dev.send_command(Command.START)  # a command: the link writes its control word from then on
        assert t.preview_write(jjr8000.point("p7"), 350)[-1] == "02 07 01 5E 00 09 00 00"
        assert [p.frames for p in t.plan([jjr8000.point("p3")], True)] == [0, 2]


class MisEcho(Channel):
    """A channel to a slave whose write echo is wrong (a broken gateway mapping, say)."""

    def __init__(self, slave: SimulatedDpSlave) -> None:
        self.inner = SimChannel(slave)
        self.ppo = slave.ppo

    def exchange(self, out_words: Sequence[int | None]) -> tuple[int, ...]:
        words = self.inner.exchange(out_words)
        task = out_words[0]  # IND of the PKW task; None keeps the previous output
        if task is not None and task >> 8 == 2 and words[0] >> 8 == 1:
            return (words[0], words[1] + 1, *words[2:])
        return words

    def snapshot(self) -> Snapshot:
        return self.inner.snapshot()


def test_a_wrong_write_echo_is_a_decode_error(jjr8000: Profile) -> None:
    class Transport(ProfibusPkwTransport):
        def make_channel(self) -> Channel:
            return MisEcho(SimulatedDpSlave(SimulatedStarter(jjr8000), Ppo.PPO1))

    transport = Transport(DeviceUrl.parse("profibus-pkw+sim://?cycle=0"), jjr8000)
    with Device(transport, jjr8000) as dev, pytest.raises(DecodeError, match="does not echo the task"):
        dev.write("ramp_time", 20)
