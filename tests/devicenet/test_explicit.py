"""Explicit message bodies in 8/8 format: requests, responses, error responses (docs/manuals.md#explicit-messages)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from starterbus.core import DecodeError, EncodeError, RemoteDeviceError
from starterbus.transports.devicenet.codec import cip
from starterbus.transports.devicenet.codec.cip import (
    CipStatus,
    FrameTooShortError,
    Service,
    UnexpectedFrameError,
    UnknownServiceError,
)
from starterbus.transports.devicenet.codec.explicit import (
    ErrorResponse,
    ExplicitRequest,
    ExplicitResponse,
    Header,
    check_response,
    decode_header,
    decode_message,
    decode_request,
    decode_response,
)

# (hex message, decoded) - requests as docs/manuals.md#explicit-messages prints them
REQUESTS = [
    # Allocate explicit + polled by master 0 on the group 2 only port: [M][4B][03][01][choice][allocator]
    ("00 4B 03 01 03 00", ExplicitRequest(0, Service.ALLOCATE, 3, 1, None, b"\x03\x00")),
    # Release: [M][4C][03][01][choice]
    ("00 4C 03 01 03", ExplicitRequest(0, Service.RELEASE, 3, 1, None, b"\x03")),
    # Set expected packet rate, the example of docs/manuals.md#allocation-and-connections (master MAC 10, value 0)
    ("0A 10 05 02 09 00 00", ExplicitRequest(10, Service.SET_ATTRIBUTE_SINGLE, 5, 2, 9, b"\x00\x00")),
    # Get identity product name with XID 1
    ("40 0E 01 01 07", ExplicitRequest(0, Service.GET_ATTRIBUTE_SINGLE, 1, 1, 7, b"", xid=1)),
    ("3F 01 01 01", ExplicitRequest(63, Service.GET_ATTRIBUTES_ALL, 1, 1)),
    ("00 05 01 01 00", ExplicitRequest(0, Service.RESET, 1, 1, None, b"\x00")),
]
RESPONSES = [
    ("00 CB 00", ExplicitResponse(0, Service.ALLOCATE, b"\x00")),  # body format 0 = 8/8
    ("00 CC", ExplicitResponse(0, Service.RELEASE)),
    ("40 90 64 00", ExplicitResponse(0, Service.SET_ATTRIBUTE_SINGLE, b"\x64\x00", xid=1)),
    ("00 94 0C 01", ErrorResponse(0, CipStatus(0x0C, 0x01))),
    ("00 94 08 FF", ErrorResponse(0, CipStatus(0x08))),
]


@pytest.mark.parametrize(("text", "request_"), REQUESTS)
def test_request_vectors(text: str, request_: ExplicitRequest) -> None:
    message = bytes.fromhex(text)
    assert request_.encode() == message
    assert decode_request(message) == request_
    assert decode_message(message) == request_


@pytest.mark.parametrize(("text", "response"), RESPONSES)
def test_response_vectors(text: str, response: ExplicitResponse | ErrorResponse) -> None:
    message = bytes.fromhex(text)
    assert response.encode() == message
    assert decode_response(message) == response
    assert decode_message(message) == response


@pytest.mark.parametrize("text", [t for t, _ in REQUESTS])
def test_trailing_bytes_become_request_data(text: str) -> None:
    """An 8/8 request has no length field: extra bytes are data; the server judges them (0x15 too much data)."""
    message = bytes.fromhex(text) + b"\xee"
    assert decode_request(message).data.endswith(b"\xee")


def test_error_response_without_additional_code() -> None:
    assert decode_response(bytes.fromhex("00 94 16")) == ErrorResponse(0, CipStatus(0x16, 0xFF))


def test_header_bits() -> None:
    assert decode_header(0xC5) == Header(mac=5, xid=1, fragmented=True)
    assert Header(5, 1, True).encode() == 0xC5
    with pytest.raises(EncodeError):
        Header(64).encode()


@pytest.mark.parametrize(
    ("text", "error", "status"),
    [
        ("", FrameTooShortError, 0x13),
        ("00", FrameTooShortError, 0x13),
        ("00 0E 01", FrameTooShortError, 0x13),  # no instance
        ("00 0E 01 01", FrameTooShortError, 0x13),  # Get_Attribute_Single without the attribute id
        ("80 00 8E 07", UnexpectedFrameError, 0x20),  # a fragment is not a whole message
    ],
)
def test_requests_too_short_or_fragmented(text: str, error: type[DecodeError], status: int) -> None:
    with pytest.raises(error) as info:
        decode_request(bytes.fromhex(text))
    assert isinstance(info.value, cip.DeviceNetDecodeError)
    assert info.value.general_status == status
    assert f"0x{status:02X}" in str(info.value)


def test_response_decoding_errors() -> None:
    with pytest.raises(FrameTooShortError):
        decode_response(bytes.fromhex("00 94"))
    with pytest.raises(UnexpectedFrameError):
        decode_response(bytes.fromhex("00 0E 01 01 07"))  # a request
    with pytest.raises(UnexpectedFrameError):
        decode_request(bytes.fromhex("00 8E 01"))  # a response
    with pytest.raises(UnknownServiceError) as info:
        decode_response(bytes.fromhex("00 B3 01"))  # service 0x33 is not one the codec knows
    assert info.value.general_status == 0x08
    assert "0x33" in str(info.value)
    assert info.value.data == bytes.fromhex("00 B3 01")


@pytest.mark.parametrize("text", ["00 94 0C 01 00", "00 94 08 FF 12 34", "40 94 16 FF FF FF FF FF"])
def test_error_response_with_extra_bytes_is_malformed(text: str) -> None:
    message = bytes.fromhex(text)
    with pytest.raises(cip.FrameTooLongError) as info:
        decode_response(message)
    extra = message[4:].hex(" ").upper()
    assert extra in str(info.value)  # names the offending bytes
    assert info.value.data == message and info.value.field == "additional_status"


def test_check_response_maps_errors() -> None:
    request = ExplicitRequest(0, Service.ALLOCATE, 3, 1, None, b"\x03\x00")
    with pytest.raises(RemoteDeviceError) as info:
        check_response(request, ErrorResponse(0, CipStatus(0x0C, 0x01)))
    error = info.value
    assert (error.protocol, error.code, error.additional) == ("devicenet", 0x0C, 0x01)
    assert error.meaning == "object state conflict"
    assert "another master" in str(error)
    with pytest.raises(UnknownServiceError):
        check_response(request, ExplicitResponse(0, Service.RELEASE))
    with pytest.raises(UnexpectedFrameError):
        check_response(request, ExplicitResponse(0, Service.ALLOCATE, b"\x00", xid=1))
    assert check_response(request, ExplicitResponse(0, Service.ALLOCATE, b"\x00")).data == b"\x00"


def test_error_response_without_additional_has_none() -> None:
    error = ErrorResponse(0, CipStatus(0x14)).error(Service.GET_ATTRIBUTE_SINGLE)
    assert error.additional is None
    assert error.meaning == "attribute not supported"


def test_status_texts() -> None:
    assert cip.general_status_text(0x16) == "object does not exist"
    assert cip.general_status_text(0x99) == "reserved general status 0x99"
    assert cip.general_status_text(0xD0) == "object class specific status 0xD0"
    assert cip.additional_status_text(0x0B, 0x02, Service.ALLOCATE).startswith("invalid allocation")
    assert cip.additional_status_text(0x0E, 0x05, Service.SET_ATTRIBUTE_SINGLE) == "object specific code 0x05"
    assert cip.additional_status_text(0x0E, 0xFF) == "none"


def test_encode_refuses_bad_fields() -> None:
    with pytest.raises(EncodeError):
        ExplicitRequest(0, Service.GET_ATTRIBUTE_SINGLE, 1, 1).encode()  # attribute missing
    with pytest.raises(EncodeError):
        ExplicitRequest(0, Service.ALLOCATE, 3, 1, attribute=1).encode()  # Allocate takes none
    with pytest.raises(EncodeError):
        ExplicitRequest(0, 0x8E, 1, 1).encode()  # response bit in a request
    with pytest.raises(EncodeError):
        ExplicitRequest(0, Service.RESET, 256, 1).encode()
    with pytest.raises(EncodeError):
        ExplicitResponse(0, Service.ERROR_RESPONSE).encode()


macs = st.integers(0, 63)
xids = st.integers(0, 1)
payload = st.binary(max_size=20)


@given(macs, xids, st.integers(0, 0x7F), st.integers(0, 255), st.integers(0, 255), st.integers(0, 255), payload)
def test_request_round_trip(
    mac: int, xid: int, service: int, class_id: int, instance: int, attr: int, data: bytes
) -> None:
    attribute = attr if service in cip.ATTRIBUTE_SERVICES else None
    request = ExplicitRequest(mac, service, class_id, instance, attribute, data, xid)
    assert decode_request(request.encode()) == request


@given(macs, xids, st.sampled_from(sorted(s for s in Service if s != Service.ERROR_RESPONSE)), payload)
def test_response_round_trip(mac: int, xid: int, service: int, data: bytes) -> None:
    response = ExplicitResponse(mac, service, data, xid)
    assert decode_response(response.encode()) == response


@given(macs, xids, st.integers(0, 255), st.integers(0, 255))
def test_error_round_trip(mac: int, xid: int, general: int, additional: int) -> None:
    response = ErrorResponse(mac, CipStatus(general, additional), xid)
    assert decode_response(response.encode()) == response
