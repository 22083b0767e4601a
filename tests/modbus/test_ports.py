"""Where the bytes go: Windows COM port URLs, pyserial's URL handlers, the pyserial path forced on a pty, and
the rules (silence, exact length, wire time) on every path."""

from __future__ import annotations

import socket
import threading
from typing import TYPE_CHECKING

import pytest

from starterbus.core.device import open_device
from starterbus.core.errors import ConfigurationError, DecodeError, TransportError
from starterbus.core.registry import get_profile
from starterbus.core.url import DeviceUrl
from starterbus.testing import wait_until
from starterbus.transports.modbus.codec.frames import ReadRequest, ReadResponse
from starterbus.transports.modbus.driver.link import (
    Link,
    PySerialLink,
    com_port,
    device_name,
    is_pseudo_terminal,
)
from starterbus.transports.modbus.transport.rtu import ModbusRtuTransport
from starterbus.transports.modbus.url import ModbusRtuConfig

if TYPE_CHECKING:
    from starterbus.tests.modbus.conftest import PtyPeer

GOOD = ReadResponse(2, (390,)).encode()
READ = ReadRequest(2, 0x0100, 1).encode()
FAST = "timeout=0.15&retries=0"


def config(url: str) -> ModbusRtuConfig:
    return ModbusRtuConfig.from_url(DeviceUrl.parse(url), get_profile("jjr5000"))


@pytest.mark.parametrize(
    ("url", "port"),
    [
        ("modbus-rtu://COM3?unit=2", "COM3"),
        ("modbus-rtu://com10?unit=2", "COM10"),
        ("modbus-rtu:///COM12?unit=2", "COM12"),
        ("modbus-rtu:///dev/ttyUSB0?unit=2", "/dev/ttyUSB0"),
    ],
)
def test_serial_port_forms(url: str, port: str) -> None:
    cfg = config(url)
    assert cfg.path == port and cfg.variant == "" and cfg.target == port
    assert cfg.line_key[1] == port if port.startswith("COM") else cfg.line_key[1].endswith("ttyUSB0")


def test_windows_opens_com_ports_by_their_device_name() -> None:
    assert device_name("COM10", "win32") == "\\\\.\\COM10"
    assert device_name("com3", "win32") == "\\\\.\\COM3"
    assert device_name("COM3", "linux") == "COM3" and device_name("/dev/ttyS0", "win32") == "/dev/ttyS0"
    assert com_port("/COM7") == "COM7" and com_port("COM0") is None and com_port("/dev/COM3") is None


def test_a_com_port_elsewhere_is_a_clear_error() -> None:
    with pytest.raises(TransportError, match="cannot open serial port COM3") as info:
        open_device("modbus-rtu://COM3?unit=2", "jjr5000").open()
    assert "Windows" in str(info.value)


def test_pyserial_url_handlers_and_io_choice() -> None:
    rfc = config("modbus-rtu+rfc2217://10.0.0.5:4001?unit=2")
    assert rfc.variant == "rfc2217" and rfc.target == "rfc2217://10.0.0.5:4001"
    sock = config("modbus-rtu+socket://10.0.0.5:4001?unit=2")
    assert sock.target == "socket://10.0.0.5:4001" and sock.line_key == ("socket", "10.0.0.5", 4001)
    assert config("modbus-rtu:///dev/ttyUSB0?unit=2").io == "posix"
    assert config("modbus-rtu:///dev/ttyUSB0?unit=2&io=pyserial").io == "pyserial"
    for url, match in [
        ("modbus-rtu+socket://10.0.0.5?unit=2", "PORT"),
        ("modbus-rtu+rfc2217://10.0.0.5:4001/x?unit=2", "no path"),
        ("modbus-rtu+tcp://10.0.0.5:4001?unit=2&io=pyserial", "serial ports only"),
        ("modbus-rtu:///dev/ttyUSB0?unit=2&io=win32", "io"),
        ("modbus-rtu://COM3:5?unit=2", "COM port"),
        ("modbus-rtu:///dev/ttyUSB0?unit=2&timeout=0.5&quarantine=0.2", "shorter than the response timeout"),
        ("modbus-rtu:///dev/ttyUSB0?unit=2&wire_check=maybe", "wire_check"),
    ]:
        with pytest.raises(ConfigurationError, match=match):
            config(url)


def test_quarantine_defaults_to_the_timeout() -> None:
    assert config("modbus-rtu:///dev/ttyUSB0?unit=2&timeout=0.3").policy.quarantine == 0.3
    assert config("modbus-rtu:///dev/ttyUSB0?unit=2&timeout=0.3&quarantine=1").policy.quarantine == 1.0


def _link(device: object) -> Link:
    transport = device.transport  # type: ignore[attr-defined]
    assert isinstance(transport, ModbusRtuTransport)
    return transport.line.link


def test_io_pyserial_on_a_pty_keeps_the_silence_and_the_exact_length(peer: PtyPeer) -> None:
    """The pyserial path: split answers assembled, 20 ms of silence kept, bytes after the answer refused."""
    peer.serve([GOOD, [GOOD[:3], 0.01, GOOD[3:]], GOOD + b"\x00", GOOD])
    with open_device(f"modbus-rtu://{peer.path}?unit=2&{FAST}&silence=0.02&io=pyserial", "jjr5000") as device:
        assert isinstance(_link(device), PySerialLink) and not _link(device).real_serial
        assert device.read_value("motor_rated_current").value == 390
        assert device.read_value("motor_rated_current").value == 390
        with pytest.raises(DecodeError) as info:
            device.read("motor_rated_current")
        assert info.value.field == "trailing"
        assert device.read_value("motor_rated_current").value == 390
    gaps = [arrival - began for began, arrival in zip(peer.last_write_from, peer.arrivals[1:], strict=False)]
    assert len(gaps) == 3 and min(gaps) >= 0.02
    assert gaps[2] >= 0.15  # after the suspect answer: the quarantine (the timeout)


def test_the_posix_path_knows_a_pty_is_no_serial_port(peer: PtyPeer) -> None:
    assert is_pseudo_terminal(peer.slave) and not is_pseudo_terminal(-1)
    with open_device(f"modbus-rtu://{peer.path}?unit=2&{FAST}", "jjr5000") as device:
        link = _link(device)
        assert type(link) is Link and not link.real_serial


#: how often a case whose premise a loaded machine can spoil is tried
ATTEMPTS = 5


@pytest.mark.parametrize("io", ["posix", "pyserial"])
def test_wire_check_on_refuses_an_answer_faster_than_the_wire(peer: PtyPeer, io: str) -> None:
    """Forced on a pty at 9600 baud: request + answer take 14 ms on a wire, the pty delivers at once. A master
    or peer held up by a loaded machine may see the answer only later, when a wire could have brought it: then
    it is delivered, and must have been seen no sooner than the wire allows; the case is tried again. A peer
    held up past the master's wait spoils the case too (a timeout, nothing delivered), but only if the peer's
    own record says its answer was not all written before the wait ran out."""
    peer.serve([GOOD] * ATTEMPTS, wait=1.0)  # the peer stops 1 s after the last request it got
    url = f"modbus-rtu://{peer.path}?unit=2&baudrate=9600&{FAST}&wire_check=on&io={io}"
    with open_device(url, "jjr5000") as device:
        transport = device.transport
        assert isinstance(transport, ModbusRtuTransport)
        guard = transport.line.guard
        for attempt in range(ATTEMPTS):
            try:
                value = device.read_value("motor_rated_current")
            except DecodeError as exc:
                assert exc.field == "timing" and exc.data == GOOD and "sooner than request and answer" in str(exc)
                break
            except TimeoutError:
                waited_until = guard.started + 0.15  # the master's wait ended no sooner than this
                answered = attempt + 1
                assert wait_until(lambda: len(peer.replied_at) >= answered), "the peer never answered"  # noqa: B023
                # replied_at is taken after the answer's write returned: at or after the answer was all there
                assert peer.replied_at[attempt] > waited_until, "an answer there in time was taken as a timeout"
                continue
            seen_after = guard.trail_until - guard.silence - guard.started  # the master's own view
            assert value.value == 390 and seen_after >= (len(READ) + len(GOOD)) * guard.min_char_time
        else:
            pytest.fail(f"the answer was never seen sooner than the wire allows in {ATTEMPTS} attempts")


@pytest.mark.parametrize("io", ["posix", "pyserial"])
def test_wire_check_on_takes_an_answer_the_wire_could_have_brought(peer: PtyPeer, io: str) -> None:
    peer.serve([[0.03, GOOD]])
    # a timeout far beyond the answer's 30 ms: on a loaded machine the peer's thread may write it much later
    url = f"modbus-rtu://{peer.path}?unit=2&baudrate=9600&timeout=5&retries=0&wire_check=on&io={io}"
    with open_device(url, "jjr5000") as device:
        assert device.read_value("motor_rated_current").value == 390  # 30 ms later: possible on a wire


def test_pyserial_socket_url_against_a_local_listener() -> None:
    """``modbus-rtu+socket://``: pyserial's socket:// handler; exact length and trailing bytes as on a pty."""
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    received: list[bytes] = []

    def serve() -> None:
        conn, _ = server.accept()
        with conn:
            for reply in (GOOD, GOOD + b"\x01\x02", GOOD):
                received.append(conn.recv(8))
                conn.sendall(reply)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        with open_device(f"modbus-rtu+socket://127.0.0.1:{port}?unit=2&{FAST}", "jjr5000") as device:
            assert isinstance(_link(device), PySerialLink) and not _link(device).real_serial
            assert device.read_value("motor_rated_current").value == 390
            with pytest.raises(DecodeError, match="suspect"):
                device.read("motor_rated_current")
            assert device.read_value("motor_rated_current").value == 390
    finally:
        thread.join(timeout=5)
        server.close()
    assert received == [READ] * 3


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # pyserial's rfc2217 client: setDaemon, setName
def test_pyserial_rfc2217_url_against_a_local_port_server(peer: PtyPeer) -> None:
    """``modbus-rtu+rfc2217://``: a small RFC 2217 server (pyserial's PortManager) in front of a pty whose other
    end is the scripted device; a good answer is a value, trailing bytes make the answer suspect."""
    import serial
    from serial import rfc2217

    peer.serve([GOOD, GOOD + b"\x00", GOOD])
    port = serial.Serial(peer.path, timeout=0.01)
    server = socket.create_server(("127.0.0.1", 0))
    stop = threading.Event()

    def serve() -> None:
        conn, _ = server.accept()
        conn.settimeout(0.01)

        class Connection:  # what PortManager writes its telnet answers to
            write = conn.sendall

        class Uart:  # the settings the client negotiates (a pty has no baud rate and no modem lines)
            baudrate, bytesize, parity, stopbits = 9600, 8, "N", 1
            rts = dtr = break_condition = rtscts = xonxoff = cts = dsr = ri = cd = False

            def reset_input_buffer(self) -> None:
                port.reset_input_buffer()

            def reset_output_buffer(self) -> None:
                port.reset_output_buffer()

        manager = rfc2217.PortManager(Uart(), Connection())
        with conn:
            while not stop.is_set():
                data = port.read(64)
                if data:
                    conn.sendall(b"".join(manager.escape(data)))
                try:
                    received = conn.recv(64)
                except TimeoutError:
                    continue
                if not received:
                    return
                port.write(b"".join(manager.filter(received)))

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        # 1 s: the answer passes two relaying threads (the port server's, pyserial's), held up on a loaded machine
        url = f"modbus-rtu+rfc2217://127.0.0.1:{server.getsockname()[1]}?unit=2&timeout=1.0&retries=0"
        with open_device(url, "jjr5000") as device:
            assert isinstance(_link(device), PySerialLink)
            assert device.read_value("motor_rated_current").value == 390
            with pytest.raises(DecodeError, match="suspect"):
                device.read("motor_rated_current")
            assert device.read_value("motor_rated_current").value == 390
    finally:
        stop.set()
        thread.join(timeout=5)
        server.close()
        port.close()
    assert peer.received == [READ] * 3
