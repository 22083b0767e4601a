"""The client transport against the simulator, for all three models, over a real pty pair and over TCP."""

from __future__ import annotations

import os
import select
import threading
import time
import tty
from typing import TYPE_CHECKING

import pytest

from starterbus.core.device import Device, open_device
from starterbus.core.errors import ConfigurationError, RemoteDeviceError, ValidationError
from starterbus.core.model import Kind
from starterbus.core.registry import get_profile
from starterbus.core.simulator import Phase, SimulatedStarter
from starterbus.core.status import MotorState
from starterbus.transports.modbus.codec.crc import append_crc
from starterbus.transports.modbus.codec.frames import ReadRequest, ReadResponse, WriteRequest
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator
from starterbus.transports.modbus.transport.rtu import LINES, ModbusRtuTransport

if TYPE_CHECKING:
    from starterbus.tests.modbus.conftest import PtyPeer, SimFactory

MODELS = ["jjr5000", "ssd1", "jjr8000"]


def phase(starter: SimulatedStarter) -> Phase:
    """The motor state now (a call, so that type checkers do not narrow it between commands)."""
    return starter.phase


def transport(device: Device) -> ModbusRtuTransport:
    assert isinstance(device.transport, ModbusRtuTransport)
    return device.transport


@pytest.fixture(params=["pty", "tcp"])
def medium(request: pytest.FixtureRequest) -> dict[str, object]:
    return {"pty": True} if request.param == "pty" else {"tcp": ("127.0.0.1", 0)}


@pytest.mark.parametrize("model", MODELS)
def test_reads_every_point_as_the_starter_holds_it(model: str, medium: dict[str, object], make_sim: SimFactory) -> None:
    sim = make_sim(model, baudrate=19200, **medium)
    starter = sim.starters[2]
    profile = starter.profile
    with open_device(sim.url(2, timeout=0.5), model) as device:
        keys = [p.key for p in profile.points.values() if "modbus-rtu" in p.addresses]
        values = device.read(*keys)
        assert list(values) == keys
        for key, value in values.items():
            point = profile.points[key]
            if point.kind is Kind.PARAMETER:
                assert value.raw == starter.params[key], key
        requests = sim.counters.requests
    # adjacent registers were merged up to the model's limit: fewer requests than points where the limit allows
    limit = profile.transport_settings("modbus-rtu")["max_read_registers"]
    assert requests == len(keys) if limit == 1 else requests < len(keys)
    assert sim.counters.errors == 0


@pytest.mark.parametrize("model", MODELS)
def test_write_status_and_commands(model: str, medium: dict[str, object], make_sim: SimFactory) -> None:
    sim = make_sim(model, **medium)
    starter = sim.starters[2]
    profile = starter.profile
    limit = profile.role("current_limit")
    assert limit is not None
    with open_device(sim.url(2), model) as device:
        target = limit.to_engineering(limit.raw_min + 10)
        device.write(limit.key, target)
        assert starter.params[limit.key] == limit.raw_min + 10
        assert device.read_value(limit.key).value == target

        status = device.status()
        assert status.state is MotorState.READY and set(status.currents) == {"a", "b", "c"}
        assert status.mains_voltage is (True if model == "jjr5000" else None)

        device.start()
        assert phase(starter) is Phase.STARTING
        status = device.status()
        assert status.starting and status.bus_control  # bit 3 held: bit 14 reports bus control
        assert starter.control_word == 0x0009

        device.stop()
        assert phase(starter) in (Phase.STOPPING, Phase.STOPPED) and starter.control_word == 0x0008

        starter.inject_fault(6)
        status = device.status()
        assert status.fault and status.fault_code == 6 and status.fault_text == "motor overload"
        device.reset()
        assert phase(starter) is Phase.STOPPED and starter.control_word == 0x0008
        assert device.status().state is MotorState.READY


@pytest.mark.parametrize("model", MODELS)
def test_device_refusals_become_remote_errors(model: str, make_sim: SimFactory) -> None:
    sim = make_sim(model)
    starter = sim.starters[2]
    profile = starter.profile
    rated = profile.role("rated_current")
    assert rated is not None
    address = rated.addresses["modbus-rtu"]
    with open_device(sim.url(2), model) as device:
        raw = transport(device)
        with pytest.raises(RemoteDeviceError) as out_of_range:  # bypasses Device validation on purpose
            raw.write_register(address, rated.raw_max + 1)
        assert out_of_range.value.code == 3 and "illegal data value" in out_of_range.value.meaning
        with pytest.raises(RemoteDeviceError) as unmapped:
            raw.read_registers(0x00FF, 1)
        assert unmapped.value.code == 2
        limit = profile.transport_settings("modbus-rtu")["max_read_registers"]
        with pytest.raises(RemoteDeviceError) as too_many:
            raw.read_registers(0x0000, limit + 1)
        assert too_many.value.code == 3
        with pytest.raises(RemoteDeviceError) as read_only:
            raw.write_register(profile.points["status_word"].addresses["modbus-rtu"], 0)
        assert read_only.value.code == 3
        if profile.control.write_protect_key:
            device.write(profile.control.write_protect_key, 0)
            with pytest.raises(RemoteDeviceError) as protected:
                device.write(rated.key, rated.to_engineering(rated.raw_min))
            assert protected.value.code == 4 and "parameter modif" in protected.value.meaning
            assert protected.value.data == bytes.fromhex("02 86 04") + append_crc(b"\x02\x86\x04")[-2:]
        else:  # JJR8000: no exception 04; the rated current is locked while running (the device's own refusal)
            device.start()
            with pytest.raises(RemoteDeviceError) as locked:
                device.send_write(*device.validate_write(rated.key, rated.to_engineering(rated.raw_min)))
            assert locked.value.code == 3


class RawClient:
    """Raw bytes to and from the simulator's pty, to send what no client of ours would send."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)

    def ask(self, frame: bytes, wait: float = 0.3) -> bytes:
        os.write(self.fd, frame)
        data = b""
        while select.select([self.fd], [], [], wait)[0]:
            data += os.read(self.fd, 256)
            wait = 0.05  # the rest of the answer follows at once
        return data

    def close(self) -> None:
        os.close(self.fd)


def test_slave_answers_raw_frames_as_the_manual_says(make_sim: SimFactory) -> None:
    sim = make_sim("jjr5000", units=(2,))
    raw = RawClient(sim.client_path)
    try:
        fc16 = append_crc(bytes.fromhex("02 10 01 00 00 01 02 00 05"))
        assert raw.ask(fc16) == append_crc(b"\x02\x90\x01")  # exception 01: illegal function
        odd = append_crc(bytes.fromhex("02 41 00"))  # length known only from the silence after it
        assert raw.ask(odd) == append_crc(b"\x02\xc1\x01")
        good = ReadRequest(2, 0x0100, 1).encode()
        assert raw.ask(good[:-1] + b"\x00", wait=0.1) == b""  # bad CRC: no answer
        assert raw.ask(ReadRequest(3, 0x0100, 1).encode(), wait=0.1) == b""  # another unit: no answer
        assert raw.ask(ReadRequest(0, 0x0100, 1).encode(), wait=0.1) == b""  # broadcast read: no answer
        assert raw.ask(b"\x17\x42", wait=0.1) == b""  # garbage, then silence
        assert raw.ask(good) == ReadResponse(2, (sim.starters[2].params["motor_rated_current"],)).encode()
        assert raw.ask(ReadRequest(2, 0x0105, 3).encode()) == append_crc(b"\x02\x83\x02")  # covers 0x0107
        assert raw.ask(append_crc(bytes.fromhex("02 03 01 00 00 00"))) == append_crc(b"\x02\x83\x03")  # quantity 0
    finally:
        raw.close()
    assert sim.counters.errors == 2  # the bad CRC and the garbage


def test_requests_found_waiting_together_get_one_answer_the_last(make_sim: SimFactory) -> None:
    """A simulator held up (a loaded machine) finds the master's retry behind the request it gave up on: it acts
    on both, answers the last only, so no answer arrives in a later request's wait."""
    sim = make_sim("jjr5000", units=(2,))
    starter = sim.starters[2]
    rated = starter.params["motor_rated_current"]
    raw = RawClient(sim.client_path)
    try:
        write = WriteRequest(2, 0x0100, rated - 1).encode()
        read = ReadRequest(2, 0x0100, 1).encode()
        assert raw.ask(write + read) == ReadResponse(2, (rated - 1,)).encode()
        assert raw.ask(read + read) == ReadResponse(2, (rated - 1,)).encode()
    finally:
        raw.close()
    assert sim.counters.overtaken == 2 and sim.counters.requests == 4


def test_jjr8000_commands_need_the_bus_control_bit(make_sim: SimFactory) -> None:
    sim = make_sim("jjr8000")
    starter = sim.starters[2]
    with open_device(sim.url(2), "jjr8000") as device:
        transport(device).write_register(0x0000, 0x0001)  # start without bit 3: ignored
        assert phase(starter) is Phase.STOPPED
        device.start()  # 0x0009
        assert phase(starter) is Phase.STARTING


def test_multi_drop_two_units_two_threads(make_sim: SimFactory) -> None:
    """Two devices on one pty line, used from two threads at once: one line object, no interleaving."""
    sim = make_sim("jjr5000", units=(1, 2), baudrate=19200)
    errors: list[BaseException] = []
    barrier = threading.Barrier(2)

    def worker(unit: int, device: Device) -> None:
        try:
            barrier.wait()
            for i in range(15):
                device.write("ramp_time", 10 + unit * 10 + i % 5)
                values = device.read("ramp_time", "status_word", "phase_a_current", "motor_rated_current")
                assert values["ramp_time"].value == 10 + unit * 10 + i % 5
        except BaseException as exc:  # reported below
            errors.append(exc)

    devices = {unit: open_device(sim.url(unit), "jjr5000") for unit in (1, 2)}
    for device in devices.values():
        device.open()
    try:
        key = transport(devices[1]).config.line_key
        assert LINES.users(key) == 2 and transport(devices[1]).line is transport(devices[2]).line
        threads = [threading.Thread(target=worker, args=(u, d)) for u, d in devices.items()]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=30)
    finally:
        for device in devices.values():
            device.close()
    assert not errors, errors
    assert sim.counters.errors == 0
    assert sim.starters[1].params["ramp_time"] == 24 and sim.starters[2].params["ramp_time"] == 34


def test_one_line_one_setting(make_sim: SimFactory) -> None:
    sim = make_sim("jjr5000", units=(1, 2))
    with open_device(sim.url(1), "jjr5000"):
        other = open_device(sim.url(2, baudrate=19200), "jjr5000")
        with pytest.raises(ConfigurationError, match="one line has one setting"):
            other.open()
        key = other.transport.config.line_key  # type: ignore[attr-defined]
        assert LINES.users(key) == 1


def test_broadcast_write_reaches_every_unit_and_reads_are_refused(make_sim: SimFactory) -> None:
    sim = make_sim("jjr5000", units=(1, 2))
    with open_device(sim.url(0, turnaround=0.01), "jjr5000") as everyone:
        everyone.send_write(
            *everyone.validate_write("ramp_time", 33)
        )  # no answer expected: returns without waiting for a timeout
        with pytest.raises(ConfigurationError, match="broadcast"):
            everyone.read("ramp_time")
        with pytest.raises(ConfigurationError, match="broadcast"):
            everyone.status()
    with open_device(sim.url(1), "jjr5000") as one:  # the next request after the turnaround works
        assert one.read_value("ramp_time").value == 33
    assert all(s.params["ramp_time"] == 33 for s in sim.starters.values())


def test_out_of_range_write_is_refused_before_anything_is_sent(make_sim: SimFactory) -> None:
    sim = make_sim("jjr5000")
    with open_device(sim.url(2), "jjr5000") as device, pytest.raises(ValidationError):
        device.write("current_limit", 1000)
    assert sim.counters.requests == 0


def test_preview_frames_match_what_is_sent(make_sim: SimFactory) -> None:
    sim = make_sim("jjr5000")
    device = open_device(sim.url(2), "jjr5000")
    point = device.profile.point("current_limit")
    assert device.transport.preview_write(point, 380) == ["02 06 01 03 01 7C 78 74"]  # the manual's frame
    from starterbus.core.status import Command

    assert device.transport.preview_command(Command.START) == ["02 06 00 00 00 09 49 FF"]  # JJR8000 example 1
    assert len(device.transport.preview_command(Command.FAULT_RESET)) == 2
    assert sim.counters.requests == 0 and ReadRequest(2, 0, 1)  # previews send nothing


def test_profile_unit_range_and_url_errors() -> None:
    profile = get_profile("jjr8000")
    for url, match in [
        ("modbus-rtu:///dev/null?unit=248", "outside"),
        ("modbus-rtu:///dev/null", "unit"),
        ("modbus-rtu:///dev/null?unit=2&speed=9600", "unknown URL parameter"),
        ("modbus-rtu:///dev/null?unit=2&baudrate=38400", "19200"),
        ("modbus-rtu:///dev/null?unit=2&parity=X", "parity"),
        ("modbus-rtu:///dev/null?unit=2&bytesize=7", "bytesize"),
        ("modbus-rtu://dev/ttyUSB0?unit=2", "three slashes"),
        ("modbus-rtu+tcp://localhost?unit=2", "PORT"),
        ("modbus-rtu+udp://localhost:502?unit=2", "variant"),
        ("modbus-rtu:///?unit=2", "path"),
    ]:
        with pytest.raises(ConfigurationError, match=match):
            open_device(url, profile)
    with pytest.raises(ConfigurationError, match="1..245"):
        open_device("modbus-rtu:///dev/null?unit=246", "ssd1")


def test_simulator_on_a_given_port_waits_the_silence(peer: PtyPeer) -> None:
    """``port=PATH`` mode (a real serial port in the field; here the far end of a pty the test holds)."""
    profile = get_profile("ssd1")
    sim = ModbusRtuSimulator({5: SimulatedStarter(profile)}, port=peer.path, silence=0.03).start()
    try:
        assert sim.describe() == [f"modbus-rtu: {peer.path}"]
        request = ReadRequest(5, 0x0100, 2).encode()
        sent = time.monotonic()
        peer.write(request)
        answer = peer.read_frame(9, timeout=2.0)
        waited = time.monotonic() - sent
        starter = sim.starters[5]
        expected = (starter.params["motor_rated_current"], starter.params["ramp_time"])
        assert answer == ReadResponse(5, expected).encode()
        assert waited >= 0.03  # the slave kept the silent interval before answering
    finally:
        sim.close()


def test_simulator_tcp_serves_several_units_and_clients(make_sim: SimFactory) -> None:
    sim = make_sim("jjr8000", units=(1, 2, 3), tcp=("127.0.0.1", 0))
    urls = sim.client_urls()
    assert sorted(urls) == [1, 2, 3] and all(u.startswith("modbus-rtu+tcp://127.0.0.1:") for u in urls.values())
    assert sim.describe() == [f"modbus-rtu-tcp: {sim.client_path}"]
    devices = [open_device(urls[unit], "jjr8000") for unit in (1, 3)]
    for device in devices:
        device.open()
    try:
        devices[0].write("ramp_time", 30)
        devices[1].write("ramp_time", 40)
        assert [d.read_value("ramp_time").value for d in devices] == [30, 40]
    finally:
        for device in devices:
            device.close()
    assert [sim.starters[u].params["ramp_time"] for u in (1, 3)] == [30, 40]


def test_simulator_needs_exactly_one_place_and_valid_units() -> None:
    starter = SimulatedStarter(get_profile("jjr5000"))
    with pytest.raises(ConfigurationError, match="exactly one"):
        ModbusRtuSimulator({2: starter})
    with pytest.raises(ConfigurationError, match="exactly one"):
        ModbusRtuSimulator({2: starter}, pty=True, tcp=("127.0.0.1", 0))
    with pytest.raises(ValueError, match="broadcast"):
        ModbusRtuSimulator({0: starter}, pty=True)
