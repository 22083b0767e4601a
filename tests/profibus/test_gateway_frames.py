"""The Modbus codecs a Profibus gateway needs (FC16 writes, FC04 reads, beside FC03): golden bytes from the Modbus
application protocol's examples, hypothesis round trips, and the MBAP engine carrying them."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from starterbus.core.errors import DecodeError, EncodeError
from starterbus.transports.modbus.codec.frames import (
    ExceptionResponse,
    OtherRequest,
    ReadInputRequest,
    ReadInputResponse,
    ReadRequest,
    ReadResponse,
    WriteRegistersRequest,
    WriteRegistersResponse,
    decode_register_request,
    decode_request,
    decode_response,
    expected_response_length,
    request_length,
)
from starterbus.transports.modbus.master.exchange import Exchange, TransactionPolicy
from starterbus.transports.modbus.master.mbap import MbapEngine, encode_adu

units = st.integers(0, 255)
words = st.integers(0, 0xFFFF)
write_requests = st.builds(
    WriteRegistersRequest, units, st.integers(0, 0xFF00), st.lists(words, min_size=1, max_size=123).map(tuple)
)
read_requests = st.builds(ReadRequest, units, st.integers(0, 0xFF00), st.integers(1, 125))
input_requests = st.builds(ReadInputRequest, units, st.integers(0, 0xFF00), st.integers(1, 125))
gateway_requests = st.one_of(write_requests, read_requests, input_requests)


def h(text: str) -> bytes:
    return bytes.fromhex(text)


# -- golden bytes (Modbus application protocol v1.1b3, 6.4 and 6.12; the unit and CRC framing of RTU) -------------


def test_fc16_golden_bytes() -> None:
    request = WriteRegistersRequest(0x11, 0x0001, (0x000A, 0x0102))
    assert request.encode()[:-2] == h("11 10 00 01 00 02 04 00 0A 01 02")  # the spec's PDU after the unit
    assert decode_register_request(request.encode()) == request
    assert request_length(request.encode()[:7]) == len(request.encode()) == 13
    answer = WriteRegistersResponse(0x11, 0x0001, 2)
    assert answer.encode()[:-2] == h("11 10 00 01 00 02")
    assert decode_response(answer.encode(), request=request) == answer
    # as a gateway gets it over TCP: the MBAP header, then the unit and the PDU (no CRC)
    assert encode_adu(1, 0x11, request.encode()[1:-2]) == h("00 01 00 00 00 0B 11 10 00 01 00 02 04 00 0A 01 02")


def test_fc04_golden_bytes() -> None:
    request = ReadInputRequest(0x11, 0x0008, 1)
    assert request.encode()[:-2] == h("11 04 00 08 00 01")
    assert decode_register_request(request.encode()) == request
    answer = ReadInputResponse(0x11, (0x000A,))
    assert answer.encode()[:-2] == h("11 04 02 00 0A")
    assert decode_response(answer.encode(), request=request) == answer
    assert isinstance(decode_response(answer.encode()), ReadInputResponse)


def test_a_starter_still_takes_fc04_and_fc16_as_other_requests() -> None:
    """decode_request is what a simulated starter serves: FC04 and FC16 stay unsupported there (exception 01)."""
    fc16 = WriteRegistersRequest(2, 0x100, (1, 2)).encode()
    assert decode_request(fc16) == OtherRequest(2, 0x10, fc16[2:-2])
    fc04 = ReadInputRequest(2, 0, 1).encode()
    assert decode_request(fc04) == OtherRequest(2, 0x04, fc04[2:-2])


# -- round trips ------------------------------------------------------------------------------------------------


@given(gateway_requests)
def test_request_round_trip(request: WriteRegistersRequest | ReadRequest) -> None:
    frame = request.encode()
    assert request_length(frame[:7]) == len(frame)
    assert decode_register_request(frame) == request
    assert decode_register_request(frame[:-2], crc=False) == request


@given(gateway_requests, st.data())
def test_response_round_trip(request: WriteRegistersRequest | ReadRequest, data: st.DataObject) -> None:
    answer: ReadResponse | WriteRegistersResponse
    if isinstance(request, WriteRegistersRequest):
        answer = WriteRegistersResponse(request.unit, request.address, len(request.values))
    else:
        values = tuple(data.draw(st.lists(words, min_size=request.count, max_size=request.count)))
        answer = (ReadInputResponse if request.function == 4 else ReadResponse)(request.unit, values)
    frame = answer.encode()
    assert len(frame) == expected_response_length(request)
    assert decode_response(frame, request=request) == answer
    assert decode_response(frame[:-2], crc=False, request=request) == answer
    code = data.draw(st.integers(1, 255))
    refusal = ExceptionResponse(request.unit, request.function, code)
    assert decode_response(refusal.encode(), request=request) == refusal


@given(write_requests, st.data())
def test_an_fc16_answer_for_other_registers_is_refused(request: WriteRegistersRequest, data: st.DataObject) -> None:
    address = data.draw(st.integers(0, 0xFFFF))
    count = data.draw(st.integers(0, 0xFFFF))
    answer = WriteRegistersResponse(request.unit, address, count)
    if (address, count) == (request.address, len(request.values)):
        return
    with pytest.raises(DecodeError) as info:
        decode_response(answer.encode(), request=request)
    assert info.value.field == "echo"


def test_a_read_answered_with_the_other_read_is_refused() -> None:
    with pytest.raises(DecodeError) as info:
        decode_response(ReadResponse(1, (5,)).encode(), request=ReadInputRequest(1, 0, 1))
    assert info.value.field == "function" and "FC04" in str(info.value)
    with pytest.raises(DecodeError):
        decode_response(ReadInputResponse(1, (5,)).encode(), request=ReadRequest(1, 0, 1))


@pytest.mark.parametrize(
    ("frame", "field"),
    [
        (h("01 10 00 01 00 02 04 00 0A 01"), "length"),  # a value short
        (h("01 10 00 01 00 02 03 00 0A 01 02"), "length"),  # a byte count that is not 2 x the count
        (h("01 04 00 01 00"), "length"),
        (h("01 06 00 01 00 02"), "function"),  # not a register gateway's request
    ],
)
def test_bad_gateway_requests_are_typed_errors(frame: bytes, field: str) -> None:
    with pytest.raises(DecodeError) as info:
        decode_register_request(frame, crc=False)
    assert info.value.field == field and info.value.data == frame


def test_encode_refuses_what_does_not_fit() -> None:
    with pytest.raises(EncodeError):
        WriteRegistersRequest(1, 0, ()).encode()
    with pytest.raises(EncodeError):
        WriteRegistersRequest(1, 0, (0,) * 124).encode()
    with pytest.raises(EncodeError):
        WriteRegistersRequest(1, 0xFFFF, (0, 0)).encode()
    with pytest.raises(EncodeError):
        WriteRegistersRequest(1, 0, (0x10000,))
    with pytest.raises(EncodeError, match="FC04"):
        ReadInputRequest(1, 0, 126).encode()


# -- the MBAP engine carries them ---------------------------------------------------------------------------------


def test_the_mbap_engine_sends_fc16_then_fc04_and_matches_their_answers() -> None:
    policy = TransactionPolicy(timeout=0.5, retries=0)
    write = Exchange(WriteRegistersRequest(3, 10, (0x0207, 350)), policy, 0.0)
    read = Exchange(ReadInputRequest(3, 20, 2), policy, 0.0)
    assert write.answer_length == 8 and read.answer_length == 9
    engine = MbapEngine(first_id=7, name="gateway gw:502")
    first, second = engine.submit(write, 0.0), engine.submit(read, 0.0)
    (adu,) = engine.take_output(0.0)  # one at a time
    assert adu == h("00 07 00 00 00 0B 03 10 00 0A 00 02 04 02 07 01 5E")
    engine.receive(encode_adu(7, 3, h("10 00 0A 00 02")), 0.01)
    assert engine.take_completed() == [first] and first.result == WriteRegistersResponse(3, 10, 2)
    (adu,) = engine.take_output(0.01)
    assert adu == h("00 08 00 00 00 06 03 04 00 14 00 02")
    engine.receive(encode_adu(7, 3, h("10 00 0A 00 02")), 0.02)  # a repeated answer to the write: stale
    engine.receive(encode_adu(8, 3, h("04 04 01 03 00 0C")), 0.02)
    assert engine.stale == 1
    assert engine.take_completed() == [second] and second.result == ReadInputResponse(3, (0x0103, 12))
