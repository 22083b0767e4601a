"""Every Modbus golden vector (docs/manuals.md#modbus-golden-vectors, docs/manuals.md#jjr8000-modbus-worked-examples),
byte for byte, through encoder, decoder and receivers.

Each vector is fed whole, byte by byte, and followed by trailing garbage. The manual's malformed JJR8000
responses must be errors naming the bytes, never values.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from starterbus.core.errors import ChecksumError, DecodeError
from starterbus.core.model import Kind
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.core.status import decode_status_word
from starterbus.transports.modbus.codec.frames import (
    ReadResponse,
    WriteRequest,
    WriteResponse,
    decode_request,
    decode_response,
)
from starterbus.transports.modbus.codec.receiver import NEED_DATA, RequestReceiver, ResponseReceiver
from starterbus.transports.modbus.slave import SlaveLogic

if TYPE_CHECKING:
    from starterbus.tests.modbus.conftest import Vector

GARBAGE = bytes.fromhex("FF 00 A5")


def feed_response(vector: Vector, chunks: list[bytes]) -> ResponseReceiver:
    receiver = ResponseReceiver(vector.request)
    for chunk in chunks:
        receiver.feed(chunk)
    return receiver


def splits(frame: bytes) -> dict[str, list[bytes]]:
    return {
        "whole": [frame],
        "byte-by-byte": [frame[i : i + 1] for i in range(len(frame))],
        "trailing": [frame + GARBAGE],
        "byte-by-byte+trailing": [b[i : i + 1] for b in (frame + GARBAGE,) for i in range(len(b))],
    }


def test_request_encodes_byte_for_byte(golden: Vector) -> None:
    assert golden.request.encode() == golden.request_frame


def test_request_decodes(golden: Vector) -> None:
    assert decode_request(golden.request_frame) == golden.request
    assert decode_request(golden.request_frame[:-2], crc=False) == golden.request


@pytest.mark.parametrize("how", ["whole", "byte-by-byte", "trailing", "byte-by-byte+trailing"])
def test_request_receiver(golden: Vector, how: str) -> None:
    receiver = RequestReceiver()
    events = []
    for chunk in splits(golden.request_frame)[how]:
        receiver.feed(chunk)
        event = receiver.next_event()
        if event is not NEED_DATA:
            events.append(event)
    assert events == [golden.request]
    assert receiver.pending == (GARBAGE if "trailing" in how else b"")


def test_response_encodes_byte_for_byte(golden: Vector) -> None:
    if golden.response is None:
        # the manual prints a malformed reply: the correct one is the echo, and it differs from the manual's
        assert isinstance(golden.request, WriteRequest)
        echo = WriteResponse(golden.request.unit, golden.request.address, golden.request.value).encode()
        assert echo == golden.request_frame != golden.response_frame
    else:
        assert golden.response.encode() == golden.response_frame


def test_response_decodes_or_is_malformed(golden: Vector) -> None:
    if golden.response is None:
        with pytest.raises(DecodeError) as info:
            decode_response(golden.response_frame, request=golden.request)
        assert info.value.field == golden.malformed_field
        assert info.value.data == golden.response_frame
        assert golden.response_frame.hex(" ").upper() in str(info.value)
    else:
        assert decode_response(golden.response_frame, request=golden.request) == golden.response
        assert decode_response(golden.response_frame[:-2], crc=False, request=golden.request) == golden.response


@pytest.mark.parametrize("how", ["whole", "byte-by-byte", "trailing", "byte-by-byte+trailing"])
def test_response_receiver(golden: Vector, how: str) -> None:
    chunks = splits(golden.response_frame)[how]
    receiver = ResponseReceiver(golden.request)
    outcome: object = NEED_DATA
    for chunk in chunks:
        receiver.feed(chunk)
        try:
            outcome = receiver.next_event()
        except DecodeError as exc:
            outcome = exc
            break
    if golden.response is not None:
        assert outcome == golden.response
        assert receiver.frame == golden.response_frame
        assert receiver.trailing == (GARBAGE if "trailing" in how else b"")
        return
    # malformed: an error, or (7-byte FC06 replies without trailing bytes) still waiting for the 8th byte
    if isinstance(outcome, DecodeError):
        assert outcome.data  # names the bytes
        if golden.malformed_field == "length":
            assert isinstance(outcome, ChecksumError)  # the garbage byte completed 8 bytes with a wrong CRC
    else:
        assert outcome is NEED_DATA and golden.malformed_field == "length" and "trailing" not in how
        error = receiver.truncated_error()
        assert error.field == "length" and error.data == golden.response_frame


def test_engineering_values(golden: Vector) -> None:
    """What a client shows for the manual's examples: 390 A, 380 %, 23.5 A, 3.50 x In, decoded status."""
    for model in golden.models:
        profile = get_profile(model)
        point = profile.by_protocol_address("modbus-rtu", Kind.MEASUREMENT, golden.register) or (
            profile.by_protocol_address("modbus-rtu", Kind.PARAMETER, golden.register)
        )
        assert point is not None, f"{model} has no register {golden.register:#06x}"
        if isinstance(golden.response, ReadResponse):
            raw = golden.response.values[0]
        else:
            assert isinstance(golden.request, WriteRequest)
            raw = golden.request.value
        if golden.engineering is not None:
            assert point.to_engineering(raw) == golden.engineering
        if golden.status:
            status = decode_status_word(raw, profile.faults)
            if golden.status == "starting":
                assert status.starting and not status.fault and point.key == "status_word"
            else:
                assert status.fault and status.fault_code == 6 and status.fault_text == "motor overload"


#: vectors whose answer depends only on parameters (status and current need a motor state the manual does not give)
SIMULATED = {
    "jjr5000-read-rated-current": {"motor_rated_current": 390},
    "jjr5000-write-current-limit": {},
    "jjr8000-read-current-limit": {},
}


@pytest.mark.parametrize("vector_id", sorted(SIMULATED))
def test_simulator_answers_the_manual(vector_id: str, vectors: tuple[Vector, ...]) -> None:
    """The slave answers the manual's requests with the manual's responses, byte for byte."""
    golden = next(v for v in vectors if v.id == vector_id)
    for model in golden.models:
        starter = SimulatedStarter(get_profile(model), values=SIMULATED[vector_id])
        answer = SlaveLogic({2: starter}).handle(decode_request(golden.request_frame))
        assert answer is not None and answer.encode() == golden.response_frame


@pytest.mark.parametrize("vector_id", ["jjr8000-start", "jjr8000-write-rated-current", "jjr8000-write-rise-time"])
def test_simulator_echoes_where_the_manual_is_malformed(vector_id: str, vectors: tuple[Vector, ...]) -> None:
    golden = next(v for v in vectors if v.id == vector_id)
    assert golden.response is None
    starter = SimulatedStarter(get_profile("jjr8000"))
    answer = SlaveLogic({2: starter}).handle(decode_request(golden.request_frame))
    assert answer is not None and answer.encode() == golden.request_frame
