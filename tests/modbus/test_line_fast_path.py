"""The line's fast path (a whole good answer decoded by the prepared exchange) agrees with the full decoder.

Anything the fast path does not accept goes to the ResponseReceiver, so bad frames keep their typed errors;
these tests pin that down for answers that start well and then go wrong, and for answers in pieces.
"""

from __future__ import annotations

import random
from typing import TYPE_CHECKING

import pytest

from starterbus.core.device import open_device
from starterbus.core.errors import ChecksumError, ConfigurationError, DecodeError, RemoteDeviceError, TimeoutError
from starterbus.transports.modbus.codec.crc import append_crc
from starterbus.transports.modbus.codec.frames import (
    ExceptionResponse,
    ReadRequest,
    ReadResponse,
    Request,
    WriteRequest,
    WriteResponse,
    decode_response,
)
from starterbus.transports.modbus.driver.line import Exchange, TransactionPolicy
from starterbus.transports.modbus.transport.rtu import ModbusRtuTransport, plan_reads, value_positions

if TYPE_CHECKING:
    from starterbus.tests.modbus.conftest import PtyPeer, SimFactory

GOOD4 = ReadResponse(2, (390, 10, 20, 380)).encode()
FAST = "timeout=0.15&retries=0"


def _good_answer(request: Request, rng: random.Random) -> bytes:
    if isinstance(request, ReadRequest):
        return ReadResponse(request.unit, tuple(rng.randrange(0x10000) for _ in range(request.count))).encode()
    assert isinstance(request, WriteRequest), request  # the test sends FC03 and FC06 only
    return WriteResponse(request.unit, request.address, request.value).encode()


def _variants(frame: bytes, rng: random.Random) -> list[bytes]:
    """Every single-byte change, some bit flips, every truncation and one byte too many."""
    out = [frame[:n] for n in range(len(frame))] + [frame + b"\x00"]
    for i in range(len(frame)):
        for value in (0x00, 0xFF, frame[i] ^ 0x80, rng.randrange(256)):
            out.append(frame[:i] + bytes([value]) + frame[i + 1 :])
    return out


def test_quick_decode_agrees_with_the_full_decoder() -> None:
    rng = random.Random(5000)
    policy = TransactionPolicy()
    requests: list[Request] = [
        ReadRequest(rng.randint(1, 247), rng.randrange(0xFF00), rng.randint(1, 125)) for _ in range(60)
    ]
    requests += [WriteRequest(rng.randint(1, 247), rng.randrange(0x10000), rng.randrange(0x10000)) for _ in range(60)]
    for request in requests:
        exchange = Exchange(request, policy, 11 / 19200)
        good = _good_answer(request, rng)
        assert exchange.quick_decode(good) == decode_response(good, request=request)
        assert exchange.quick_decode(bytes(good)) == decode_response(good, request=request)  # the same bytes again
        exception = ExceptionResponse(request.unit, request.function, 2).encode()
        assert exchange.quick_decode(exception) is None  # an answer, but the receiver's to decode
        for frame in _variants(good, rng):
            quick = exchange.quick_decode(frame)
            if quick is not None:  # only ever a frame the full decoder accepts, with the same result
                assert quick == decode_response(frame, request=request)


def test_a_changed_answer_is_decoded_again() -> None:
    exchange = Exchange(ReadRequest(2, 0x0100, 4), TransactionPolicy(), 11 / 19200)
    other = ReadResponse(2, (391, 10, 20, 380)).encode()
    bad_crc = GOOD4[:-1] + bytes([GOOD4[-1] ^ 0x01])
    for frame, good in ((GOOD4, True), (other, True), (GOOD4, True), (bad_crc, False), (other, True)):
        quick = exchange.quick_decode(frame)
        assert quick == (decode_response(frame, request=exchange.request) if good else None)


def test_good_so_far_accepts_only_the_beginning_of_a_normal_answer() -> None:
    read = Exchange(ReadRequest(2, 0x0100, 4), TransactionPolicy(), 11 / 19200)
    assert read.good_so_far(GOOD4[:5]) and read.good_so_far(GOOD4[:12])
    assert not read.good_so_far(b"\x02\x03\x06\x01\x86")  # byte count of 3 registers
    assert not read.good_so_far(b"\x02\x83\x02\xc0\xf1")  # an exception
    write = WriteRequest(2, 0x0103, 380)
    exchange = Exchange(write, TransactionPolicy(), 11 / 19200)
    assert exchange.good_so_far(write.encode()[:5])
    assert not exchange.good_so_far(b"\x02\x06\x01\x03\x02")  # not the echo


def _read4(peer: PtyPeer) -> tuple[int, ...]:
    with open_device(f"modbus-rtu://{peer.path}?unit=2&{FAST}", "jjr5000") as device:
        return device.transport.read_registers(0x0100, 4)  # type: ignore[attr-defined,no-any-return]


def test_an_answer_in_two_pieces_is_assembled(peer: PtyPeer) -> None:
    peer.serve([[GOOD4[:5], 0.01, GOOD4[5:]]])
    assert _read4(peer) == (390, 10, 20, 380)


def test_no_answer_to_a_fresh_exchange_is_a_timeout(peer: PtyPeer) -> None:
    """A fresh exchange has no last answer (empty bytes): an empty read is not that answer (RtuLine.run takes the
    same bytes as the last good answer without decoding them again)."""
    peer.serve([None])
    with pytest.raises(TimeoutError, match="no answer from unit 2"):
        _read4(peer)


def test_a_good_start_then_silence_is_truncated(peer: PtyPeer) -> None:
    peer.serve([[GOOD4[:9]]])
    with pytest.raises(DecodeError) as info:
        _read4(peer)
    assert info.value.field == "length" and "9 of 13" in str(info.value)


def test_a_good_start_then_a_bad_crc_is_a_checksum_error(peer: PtyPeer) -> None:
    bad = GOOD4[:-1] + bytes([GOOD4[-1] ^ 0x01])
    peer.serve([[bad[:5], 0.01, bad[5:]]])
    with pytest.raises(ChecksumError) as info:
        _read4(peer)
    assert info.value.data == bad


def test_a_good_header_then_wrong_words_is_not_an_echo(peer: PtyPeer) -> None:
    """A FC06 answer that starts like the echo and ends otherwise (with a right CRC) is malformed."""
    answer = append_crc(bytes.fromhex("02 06 01 03 01 7D"))
    peer.serve([answer])
    with (
        open_device(f"modbus-rtu://{peer.path}?unit=2&{FAST}", "jjr5000") as device,
        pytest.raises(DecodeError) as info,
    ):
        device.send_write(*device.validate_write("current_limit", 380))
    assert info.value.field == "echo"


def test_repeated_reads_and_writes_send_the_same_frames(peer: PtyPeer) -> None:
    write = WriteRequest(2, 0x0103, 380)
    peer.serve([GOOD4, write.encode(), GOOD4, write.encode()])
    with open_device(f"modbus-rtu://{peer.path}?unit=2&{FAST}", "jjr5000") as device:
        for _ in range(2):
            assert device.transport.read_registers(0x0100, 4) == (390, 10, 20, 380)  # type: ignore[attr-defined]
            device.transport.write_register(0x0103, 380)  # type: ignore[attr-defined]
    assert peer.received == [ReadRequest(2, 0x0100, 4).encode(), write.encode()] * 2


def test_a_broadcast_device_refuses_every_read(peer: PtyPeer) -> None:
    with open_device(f"modbus-rtu://{peer.path}?unit=0&{FAST}", "jjr5000") as device:
        for _ in range(2):
            with pytest.raises(ConfigurationError, match="broadcast"):
                device.transport.read_registers(0x0100, 4)  # type: ignore[attr-defined]
    assert peer.pending(0.05) == b""


def test_value_positions_follow_the_plan() -> None:
    addresses = (0x0105, 0x0101, 0x0102, 0x0103, 0x0109, 0x0102)
    plan = plan_reads(addresses, 4)
    assert plan == [(0x0101, 3), (0x0105, 1), (0x0109, 1)]
    assert value_positions(addresses, plan) == (3, 0, 1, 2, 4, 1)


def test_reads_in_any_order_and_repeated_keys(make_sim: SimFactory) -> None:
    sim = make_sim("jjr5000")
    params = sim.starters[2].params
    keys = ["current_limit", "motor_rated_current", "current_limit", "ramp_time"]
    with open_device(sim.url(2), "jjr5000") as device:
        for _ in range(2):  # the second time from the cached plan
            readings = device.transport.read_points(device.resolve(keys))
            assert [r.raw for r in readings] == [params[k] for k in keys]


def test_the_counters_count_what_the_wire_saw(peer: PtyPeer) -> None:
    """A good answer, one after a timeout, an exception answer, then no answer at all (two attempts each)."""
    refusal = ExceptionResponse(2, 3, 2).encode()
    peer.serve([GOOD4, None, GOOD4, refusal, None, None])
    url = f"modbus-rtu://{peer.path}?unit=2&baudrate=19200&timeout=0.1&retries=1"
    with open_device(url, "jjr5000") as device:
        transport = device.transport
        assert isinstance(transport, ModbusRtuTransport)
        seen: list[object] = []
        for _ in range(4):
            try:
                transport.read_registers(0x0100, 4)
            except (RemoteDeviceError, TimeoutError) as exc:
                seen.append(type(exc))
            c = transport.counters()
            seen.append((c.transactions, c.requests, c.retries, c.timeouts, c.errors, c.bytes_sent, c.bytes_received))
        silence = transport.config.serial.silence
    assert seen == [
        (1, 1, 0, 0, 0, 8, 13),
        (2, 3, 1, 0, 0, 24, 26),
        RemoteDeviceError,
        (3, 4, 1, 0, 0, 32, 31),  # a refusal is an answer (5 bytes), not an error
        TimeoutError,
        (4, 6, 2, 1, 1, 48, 31),
    ]
    assert c.wire_time == pytest.approx((48 + 31) * 11 / 19200 + 2 * 6 * silence)
