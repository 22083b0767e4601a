"""The sans-IO codec: CRC, frames, receivers. Hypothesis round trips, corruption and cross-checks with pymodbus."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymodbus.framer.rtu import FramerRTU
from pymodbus.pdu import DecodePDU
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersRequest,
    ReadHoldingRegistersResponse,
    WriteSingleRegisterRequest,
)

from starterbus.core.errors import ChecksumError, CodecError, DecodeError, EncodeError
from starterbus.transports.modbus.codec.crc import TABLE, append_crc, crc16, strip_crc
from starterbus.transports.modbus.codec.frames import (
    ExceptionResponse,
    OtherRequest,
    ReadRequest,
    ReadResponse,
    WriteRequest,
    WriteResponse,
    decode_request,
    decode_response,
    expected_response_length,
    request_length,
)
from starterbus.transports.modbus.codec.receiver import NEED_DATA, RequestReceiver, ResponseReceiver

units = st.integers(0, 255)
words = st.integers(0, 0xFFFF)
read_requests = st.builds(ReadRequest, units, st.integers(0, 0xFF00), st.integers(1, 125))
write_requests = st.builds(WriteRequest, units, words, words)
requests = st.one_of(read_requests, write_requests)


def bitwise_crc(data: bytes) -> int:
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def answer_to(request: ReadRequest | WriteRequest, data: st.DataObject) -> ReadResponse | WriteResponse:
    if isinstance(request, ReadRequest):
        values = data.draw(st.lists(words, min_size=request.count, max_size=request.count))
        return ReadResponse(request.unit, tuple(values))
    return WriteResponse(request.unit, request.address, request.value)


# -- CRC ------------------------------------------------------------------------------------------------------


def test_crc_check_value_and_table() -> None:
    assert crc16(b"123456789") == 0x4B37  # the CRC-16/MODBUS catalogue check value
    assert len(TABLE) == 256 and TABLE[1] == 0xC0C1
    assert append_crc(bytes.fromhex("02 03 01 00 00 01")) == bytes.fromhex("02 03 01 00 00 01 85 C5")


@given(st.binary(max_size=300))
def test_crc_matches_bitwise_and_pymodbus(data: bytes) -> None:
    assert crc16(data) == bitwise_crc(data)
    assert crc16(data).to_bytes(2, "little") == FramerRTU.compute_CRC(data).to_bytes(2, "big")
    assert crc16(append_crc(data)) == 0  # the residue of a frame with its CRC


def test_strip_crc_names_the_right_crc() -> None:
    with pytest.raises(ChecksumError) as info:
        strip_crc(bytes.fromhex("02 03 02 01 86 7C 77"))
    assert "7C 77" in str(info.value) and "7C 76" in str(info.value)
    assert info.value.data == bytes.fromhex("02 03 02 01 86 7C 77") and info.value.field == "crc"
    with pytest.raises(DecodeError):
        strip_crc(b"\x02\x03")


# -- round trips --------------------------------------------------------------------------------------------------


@given(requests)
def test_request_round_trip(request: ReadRequest | WriteRequest) -> None:
    frame = request.encode()
    assert len(frame) == 8 == request_length(frame[:2])
    assert decode_request(frame) == request


@given(requests, st.data())
def test_response_round_trip(request: ReadRequest | WriteRequest, data: st.DataObject) -> None:
    response = answer_to(request, data)
    frame = response.encode()
    assert len(frame) == expected_response_length(request)
    assert decode_response(frame, request=request) == response
    assert decode_response(frame) == response


@given(st.integers(1, 255), st.integers(1, 0x7F), st.integers(0, 255))
def test_exception_round_trip(unit: int, function: int, code: int) -> None:
    response = ExceptionResponse(unit, function, code)
    frame = response.encode()
    assert len(frame) == 5 and frame[1] == function | 0x80
    assert decode_response(frame) == response


@given(requests)
def test_pymodbus_builds_the_same_requests(request: ReadRequest | WriteRequest) -> None:
    framer = FramerRTU(DecodePDU(False))
    if isinstance(request, ReadRequest):
        read = ReadHoldingRegistersRequest(address=request.address, count=request.count, dev_id=request.unit)
        assert framer.buildFrame(read) == request.encode()
    else:
        write = WriteSingleRegisterRequest(address=request.address, registers=[request.value], dev_id=request.unit)
        assert framer.buildFrame(write) == request.encode()


@given(read_requests, st.data())
def test_pymodbus_decodes_our_responses(request: ReadRequest, data: st.DataObject) -> None:
    response = answer_to(request, data)
    assert isinstance(response, ReadResponse)
    used, pdu = FramerRTU(DecodePDU(False)).handleFrame(response.encode(), 0, 0)
    assert isinstance(pdu, ReadHoldingRegistersResponse)
    assert used == len(response.encode()) and tuple(pdu.registers) == response.values


# -- corruption never yields a value -------------------------------------------------------------------------------


@given(requests, st.data())
def test_any_single_bit_flip_is_an_error(request: ReadRequest | WriteRequest, data: st.DataObject) -> None:
    frame = bytearray(answer_to(request, data).encode())
    bit = data.draw(st.integers(0, 8 * len(frame) - 1))
    frame[bit // 8] ^= 1 << (bit % 8)
    with pytest.raises(DecodeError):
        decode_response(bytes(frame), request=request)
    receiver = ResponseReceiver(request)
    receiver.feed(bytes(frame) + b"\x00" * 300)
    with pytest.raises(DecodeError):
        receiver.next_event()


@given(st.binary(max_size=40), requests)
def test_random_bytes_decode_to_an_error_or_their_exact_frame(data: bytes, request: ReadRequest | WriteRequest) -> None:
    for decode in (decode_request, decode_response):
        try:
            result = decode(data)
        except DecodeError:
            continue
        assert result.encode() == data  # only a frame with a good CRC and an exact layout decodes
    receiver = ResponseReceiver(request)
    receiver.feed(data)
    try:
        event = receiver.next_event()
    except DecodeError as exc:
        assert exc.data  # names the bytes
        return
    if event is not NEED_DATA:
        assert event.encode() == receiver.frame


@given(requests, st.data(), st.binary(max_size=10))
def test_receiver_any_chunking(request: ReadRequest | WriteRequest, data: st.DataObject, tail: bytes) -> None:
    response = answer_to(request, data)
    stream = response.encode() + tail
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=6)))
    receiver = ResponseReceiver(request)
    events = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        receiver.feed(stream[a:b])
        if receiver.bytes_needed() == 0 or b == len(stream):
            event = receiver.next_event()
            if event is not NEED_DATA:
                events.append(event)
    assert events and events[-1] == response
    assert receiver.trailing == tail


# -- answers checked against the request ------------------------------------------------------------------------------


REQ = ReadRequest(2, 0x0100, 1)


@pytest.mark.parametrize(
    ("frame", "field"),
    [
        (ReadResponse(3, (390,)).encode(), "unit"),  # another slave answered
        (WriteResponse(2, 0x0100, 390).encode(), "function"),
        (ExceptionResponse(2, 6, 2).encode(), "function"),
        (ReadResponse(2, (390, 1)).encode(), "byte_count"),
        (b"\xff" + ReadResponse(2, (390,)).encode(), "unit"),  # garbage first
        (ReadResponse(2, (390,)).encode()[:-1] + b"\x00", "crc"),
    ],
    ids=["wrong-unit", "wrong-function", "exception-for-other-function", "byte-count", "garbage-first", "crc"],
)
def test_bad_answers_are_typed_errors(frame: bytes, field: str) -> None:
    with pytest.raises(DecodeError) as info:
        decode_response(frame, request=REQ)
    assert info.value.field == field and info.value.data == frame
    receiver = ResponseReceiver(REQ)
    receiver.feed(frame)
    with pytest.raises(DecodeError) as again:
        receiver.next_event()
    assert again.value.field == field
    with pytest.raises(DecodeError):  # the receiver stays failed
        receiver.next_event()


def test_receiver_reads_the_header_first_then_the_rest() -> None:
    receiver = ResponseReceiver(ReadRequest(2, 0, 4))
    assert receiver.expected_length == 13 and receiver.bytes_needed() == 5
    receiver.feed(ReadResponse(2, (1, 2, 3, 4)).encode()[:5])
    assert receiver.next_event() is NEED_DATA and receiver.bytes_needed() == 8
    exception = ResponseReceiver(ReadRequest(2, 0, 4))
    exception.feed(ExceptionResponse(2, 3, 3).encode())
    assert exception.next_event() == ExceptionResponse(2, 3, 3) and exception.bytes_needed() == 0
    truncated = ResponseReceiver(ReadRequest(2, 0, 4))
    truncated.feed(b"\x02\x03\x08\x00")
    assert truncated.next_event() is NEED_DATA
    error = truncated.truncated_error()
    assert "4 of 13" in str(error) and error.data == b"\x02\x03\x08\x00"


def test_request_receiver_splits_back_to_back_frames_and_unknown_functions() -> None:
    receiver = RequestReceiver()
    a, b = ReadRequest(1, 0, 1).encode(), WriteRequest(2, 0x103, 7).encode()
    fc16 = append_crc(bytes.fromhex("02 10 01 00 00 02 04 00 01 00 02"))
    receiver.feed(a + b + fc16)
    assert receiver.next_event() == ReadRequest(1, 0, 1)
    assert receiver.next_event() == WriteRequest(2, 0x103, 7)
    assert receiver.next_event() == OtherRequest(2, 0x10, fc16[2:-2])
    assert receiver.next_event() is NEED_DATA and receiver.bytes_needed() == 2
    odd = append_crc(bytes.fromhex("02 41 12 34"))  # a function code whose length only silence tells
    receiver.feed(odd)
    assert receiver.next_event() is NEED_DATA and receiver.bytes_needed() is None
    assert receiver.end_of_frame() == OtherRequest(2, 0x41, b"\x12\x34")
    receiver.feed(a[:5])
    with pytest.raises(DecodeError, match="truncated request"):
        receiver.end_of_frame()
    receiver.feed(a[:-1] + b"\x00")
    with pytest.raises(ChecksumError):
        receiver.next_event()


@pytest.mark.parametrize(
    "build",
    [
        lambda: ReadRequest(2, 0, 0).encode(),
        lambda: ReadRequest(2, 0, 126).encode(),
        lambda: ReadRequest(2, 0xFFFF, 2).encode(),
        lambda: ReadRequest(256, 0, 1),
        lambda: WriteRequest(2, 0, 0x10000),
        lambda: WriteRequest(2, -1, 0),
        lambda: ReadResponse(2, ()),
        lambda: ExceptionResponse(2, 0x83, 1),
        lambda: OtherRequest(2, 3),
    ],
)
def test_encode_refuses_what_does_not_fit(build: object) -> None:
    with pytest.raises(EncodeError):
        build()  # type: ignore[operator]


def test_decode_errors_are_codec_errors_with_the_bytes() -> None:
    for frame in (b"", b"\x02", append_crc(b"\x02\x83\x02\x00"), append_crc(b"\x02\x03\x03\x00\x01\x02")):
        with pytest.raises(CodecError) as info:
            decode_response(frame)
        assert info.value.data == frame
    with pytest.raises(DecodeError, match="exception bit"):
        decode_request(append_crc(b"\x02\x83\x02"))
