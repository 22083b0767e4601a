"""A scripted 'device' on the other end of a real pty (or a TCP socket) says wrong things: each is a typed error.

No answer ever becomes a value: corrupted CRC, truncated frames, garbage first, silence, another unit,
another function, non-echoes; exception responses carry the model's meaning. Retries are bounded and a write
is repeated only with retry_writes=1. An invalid write sends nothing at all.
"""

from __future__ import annotations

import builtins
import socket
import threading
import time
from typing import TYPE_CHECKING

import pytest

from starterbus.core.device import Device, open_device
from starterbus.core.errors import (
    ChecksumError,
    DecodeError,
    RemoteDeviceError,
    StarterbusError,
    TimeoutError,
    TransportError,
    ValidationError,
)
from starterbus.core.status import Command
from starterbus.testing import wait_until
from starterbus.transports.modbus.codec.crc import append_crc
from starterbus.transports.modbus.codec.frames import (
    ExceptionResponse,
    ReadRequest,
    ReadResponse,
    WriteRequest,
    WriteResponse,
)

if TYPE_CHECKING:
    from starterbus.tests.modbus.conftest import PtyPeer

READ = ReadRequest(2, 0x0100, 1)  # motor rated current, JJR5000
GOOD = ReadResponse(2, (390,)).encode()
FAST = "timeout=0.15&retries=0"


def device(peer: PtyPeer, params: str = FAST, model: str = "jjr5000") -> Device:
    return open_device(f"modbus-rtu://{peer.path}?unit=2&{params}", model)


def read_rated(peer: PtyPeer, params: str = FAST) -> object:
    with device(peer, params) as d:
        return d.read_value("motor_rated_current")


def test_a_good_answer_is_a_value(peer: PtyPeer) -> None:
    peer.serve([GOOD])
    value = read_rated(peer)
    assert value.value == 390  # type: ignore[attr-defined]
    assert peer.received == [READ.encode()]


@pytest.mark.parametrize(
    ("reply", "error", "field"),
    [
        (GOOD[:-1] + bytes([GOOD[-1] ^ 0x01]), ChecksumError, "crc"),
        (b"\xff" + GOOD, DecodeError, "unit"),  # garbage first
        (ReadResponse(3, (390,)).encode(), DecodeError, "unit"),  # another slave answers
        (WriteResponse(2, 0x0100, 390).encode(), DecodeError, "function"),
        (ReadResponse(2, (390, 0)).encode(), DecodeError, "byte_count"),
        ([GOOD[:4]], DecodeError, "length"),  # truncated, then silence
    ],
    ids=["crc", "garbage-first", "wrong-unit", "wrong-function", "byte-count", "truncated"],
)
def test_bad_answers_are_typed_errors(peer: PtyPeer, reply: object, error: type[DecodeError], field: str) -> None:
    peer.serve([reply])  # type: ignore[list-item,unused-ignore]
    with pytest.raises(error) as info:
        read_rated(peer)
    assert info.value.field == field and info.value.data  # names the bytes
    assert "attempt 1 of 1" in str(info.value)


def test_silence_is_a_timeout(peer: PtyPeer) -> None:
    peer.serve([None])
    started = time.monotonic()
    with pytest.raises(TimeoutError) as info:
        read_rated(peer)
    assert isinstance(info.value, builtins.TimeoutError) and isinstance(info.value, TransportError)
    assert "no answer from unit 2" in str(info.value) and "02 03 01 00 00 01 85 C5" in str(info.value)
    assert time.monotonic() - started < 2.0  # bounded by the timeout


def test_exception_response_carries_the_models_meaning(peer: PtyPeer) -> None:
    peer.serve([ExceptionResponse(2, 6, 4).encode()])
    with device(peer) as d, pytest.raises(RemoteDeviceError) as info:
        d.send_write(*d.validate_write("current_limit", 380))
    assert info.value.code == 4 and info.value.protocol == "modbus-rtu"
    assert "parameter modify" in info.value.meaning.lower()
    assert info.value.data == ExceptionResponse(2, 6, 4).encode()


def test_exception_code_unknown_to_the_model(peer: PtyPeer) -> None:
    peer.serve([ExceptionResponse(2, 3, 4).encode()])
    with device(peer, model="jjr8000") as d, pytest.raises(RemoteDeviceError) as info:
        d.read("motor_rated_current")
    assert info.value.code == 4 and "unknown exception code 4" in info.value.meaning


def test_manual_non_echo_is_malformed(peer: PtyPeer) -> None:
    """JJR8000 example 1 as printed: the start command answered with 02 06 00 00 00 00."""
    peer.serve([append_crc(bytes.fromhex("02 06 00 00 00 00"))])
    with device(peer, model="jjr8000") as d, pytest.raises(DecodeError) as info:
        d.send_command(Command.START)
    assert info.value.field == "echo"
    assert peer.received == [bytes.fromhex("02 06 00 00 00 09 49 FF")]


def test_manual_short_write_answer_is_malformed(peer: PtyPeer) -> None:
    """JJR8000 example 5 as printed: 02 06 02 01 90 (+CRC) is one byte short of an echo."""
    peer.serve([append_crc(bytes.fromhex("02 06 02 01 90"))])
    with device(peer, model="jjr8000") as d, pytest.raises(DecodeError) as info:
        d.send_write(*d.validate_write("motor_rated_current", 400))
    assert info.value.field == "length" and "7 of 8" in str(info.value)


def test_answer_split_in_pieces_is_assembled(peer: PtyPeer) -> None:
    peer.serve([[GOOD[:2], 0.01, GOOD[2:5], 0.01, GOOD[5:]]])
    assert read_rated(peer).value == 390  # type: ignore[attr-defined]


def test_reads_are_retried_within_the_limit(peer: PtyPeer) -> None:
    peer.serve([b"\x00\x00garbage", None, GOOD])
    # 0.5 s: the peer's thread answers the third request in time even when a loaded machine holds it up
    assert read_rated(peer, "timeout=0.5&retries=2").value == 390  # type: ignore[attr-defined]
    assert peer.received == [READ.encode()] * 3


def test_retries_are_bounded(peer: PtyPeer) -> None:
    peer.serve([None, None, None, GOOD], wait=0.5)
    with pytest.raises(TimeoutError, match="attempt 2 of 2"):
        read_rated(peer, "timeout=0.1&retries=1")
    peer.join()
    assert len(peer.received) == 2


def test_a_write_is_not_repeated_after_it_may_have_executed(peer: PtyPeer) -> None:
    write = WriteRequest(2, 0x0103, 380).encode()
    peer.serve([None, write], wait=0.5)
    with device(peer, "timeout=0.1&retries=3") as d, pytest.raises(TimeoutError, match="not repeated"):
        d.send_write(*d.validate_write("current_limit", 380))
    assert peer.received == [write] and peer.pending(0.2) == b""


def test_a_write_is_repeated_when_allowed(peer: PtyPeer) -> None:
    write = WriteRequest(2, 0x0103, 380).encode()
    peer.serve([None, write])
    with device(peer, "timeout=0.1&retries=3&retry_writes=1") as d:
        d.send_write(*d.validate_write("current_limit", 380))
    assert peer.received == [write, write]


def test_invalid_write_sends_nothing(peer: PtyPeer) -> None:
    with device(peer) as d:
        bad: list[tuple[str, float | int | str]] = [
            ("current_limit", 1000), ("current_limit", 380.5), ("start_mode", "sideways"),
        ]  # fmt: skip
        for key, value in bad:
            with pytest.raises(ValidationError):
                d.write(key, value)
        with pytest.raises(ValidationError):
            d.write_many({"ramp_time": 10, "current_limit": 1000})  # one bad value: nothing at all is written
        assert peer.pending(0.1) == b""  # the line saw zero bytes
        peer.serve([GOOD])
        assert d.read_value("motor_rated_current").value == 390
    assert peer.received == [READ.encode()]


def test_the_silent_interval_is_kept_between_frames(peer: PtyPeer) -> None:
    """With silence=20 ms, the next request never starts sooner than 20 ms after the last answer byte."""
    peer.serve([GOOD, GOOD, GOOD])
    with device(peer, FAST + "&silence=0.02") as d:
        for _ in range(3):
            d.read("motor_rated_current")
    gaps = [arrival - began for began, arrival in zip(peer.last_write_from, peer.arrivals[1:], strict=False)]
    assert len(gaps) == 2 and min(gaps) >= 0.02


def test_late_answer_from_an_earlier_request_is_not_taken(peer: PtyPeer) -> None:
    """An answer arriving after the timeout is drained before the next request on the line, never taken as its
    answer. The next request is a second device's on the same line (one line, one guard), whose timeout a peer
    held up on a loaded machine does not reach (its quarantine, as long, starts at the stray: sent 1 s later)."""
    late = ReadResponse(2, (111,)).encode()
    peer.serve([[0.5, late], GOOD])
    with device(peer, "timeout=0.1&retries=0") as d, device(peer, "timeout=1&retries=0") as patient:
        assert patient.transport.line is d.transport.line  # type: ignore[attr-defined]
        with pytest.raises(TimeoutError):
            d.read("motor_rated_current")
        assert wait_until(lambda: len(peer.replied_at) == 1)  # the late answer is now waiting on the line
        assert patient.read_value("motor_rated_current").value == 390


def test_peer_hangs_up_is_a_transport_error_then_reconnects() -> None:
    """A device server that drops the connection: a TransportError, and the next transaction reconnects."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(2)
    port = server.getsockname()[1]

    def hang_up_then_answer() -> None:
        conn, _ = server.accept()
        conn.recv(8)
        conn.close()
        conn, _ = server.accept()
        with conn:
            conn.recv(8)
            conn.sendall(GOOD)

    thread = threading.Thread(target=hang_up_then_answer, daemon=True)
    thread.start()
    try:
        with open_device(f"modbus-rtu+tcp://127.0.0.1:{port}?unit=2&{FAST}", "jjr5000") as d:
            with pytest.raises(TransportError, match="closed"):
                d.read("motor_rated_current")
            assert d.read_value("motor_rated_current").value == 390
    finally:
        thread.join(timeout=2)
        server.close()


def test_tcp_scripted_peer_garbage_and_crc() -> None:
    """The same rules over TCP: a bad CRC is an error, a good answer a value."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]

    def script() -> None:
        conn, _ = server.accept()
        with conn:
            for reply in (GOOD[:-1] + b"\x00", GOOD):
                conn.recv(8)
                conn.sendall(reply)

    thread = threading.Thread(target=script, daemon=True)
    thread.start()
    try:
        with open_device(f"modbus-rtu+tcp://127.0.0.1:{port}?unit=2&{FAST}", "jjr5000") as d:
            with pytest.raises(ChecksumError):
                d.read("motor_rated_current")
            assert d.read_value("motor_rated_current").value == 390
    finally:
        thread.join(timeout=2)
        server.close()


def test_nothing_to_connect_to() -> None:
    with pytest.raises(TransportError, match="cannot open serial port"):
        open_device("modbus-rtu:///dev/does-not-exist?unit=2", "jjr5000").open()
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    with pytest.raises(StarterbusError, match="cannot connect"):
        open_device(f"modbus-rtu+tcp://127.0.0.1:{port}?unit=2", "jjr5000").open()
