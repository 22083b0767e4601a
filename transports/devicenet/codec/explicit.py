"""Explicit messages in the DeviceNet 8/8 body format: requests, success responses and error responses.

A *message* here is the header byte followed by the body, exactly as one unfragmented CAN frame carries it
(or as :mod:`~starterbus.transports.devicenet.codec.fragmentation` reassembles it)::

    header   bit 7 fragmented, bit 6 transaction id (XID), bits 5-0 MAC id (the master's, both directions)
    request  [header][service][class][instance][attribute, Get/Set_Attribute_Single only][data...]
    response [header][service | 0x80][data...]
    error    [header][0x94][general status][additional status, 0xFF = none]

Pure functions, no I/O. Decoders raise :class:`~starterbus.transports.devicenet.codec.cip.DeviceNetDecodeError`
subclasses that name the bytes and the CIP status a server answers with.
"""

from __future__ import annotations

from dataclasses import dataclass

from starterbus.core import EncodeError, RemoteDeviceError
from starterbus.transports.devicenet.codec.cip import (
    ATTRIBUTE_SERVICES,
    NO_ADDITIONAL,
    CipStatus,
    FrameTooLongError,
    FrameTooShortError,
    Service,
    UnexpectedFrameError,
    UnknownServiceError,
    remote_error,
    service_name,
)

FRAGMENT_BIT = 0x80
XID_BIT = 0x40
MAC_MASK = 0x3F
RESPONSE_BIT = 0x80
ERROR_SERVICE = 0x94  # Error_Response (0x14) with the response bit
MAX_UNFRAGMENTED = 8


@dataclass(frozen=True, slots=True)
class Header:
    """The first byte of every explicit message frame."""

    mac: int
    xid: int = 0
    fragmented: bool = False

    def encode(self) -> int:
        if not 0 <= self.mac <= MAC_MASK:
            raise EncodeError(f"MAC id {self.mac!r} is outside 0..63", field="header.mac")
        if self.xid not in (0, 1):
            raise EncodeError(f"transaction id {self.xid!r} is not 0 or 1", field="header.xid")
        return (FRAGMENT_BIT if self.fragmented else 0) | (XID_BIT if self.xid else 0) | self.mac


def decode_header(byte: int) -> Header:
    return Header(mac=byte & MAC_MASK, xid=1 if byte & XID_BIT else 0, fragmented=bool(byte & FRAGMENT_BIT))


def _byte(name: str, value: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFF:
        raise EncodeError(f"{value!r} does not fit one byte", field=name)
    return value


@dataclass(frozen=True, slots=True)
class ExplicitRequest:
    """A request in 8/8 format (class and instance one byte each)."""

    mac: int
    service: int
    class_id: int
    instance: int
    attribute: int | None = None
    data: bytes = b""
    xid: int = 0

    def body(self) -> bytes:
        if not 0 <= self.service <= 0x7F:
            raise EncodeError(f"service 0x{self.service:X} has the response bit set or is too large", field="service")
        out = bytearray((self.service, _byte("class", self.class_id), _byte("instance", self.instance)))
        if self.service in ATTRIBUTE_SERVICES:
            if self.attribute is None:
                raise EncodeError(f"{service_name(self.service)} needs an attribute id", field="attribute")
            out.append(_byte("attribute", self.attribute))
        elif self.attribute is not None:
            raise EncodeError(f"{service_name(self.service)} takes no attribute id", field="attribute")
        return bytes(out) + bytes(self.data)

    def encode(self) -> bytes:
        """Header + body; longer than 8 bytes means the caller must fragment it."""
        return bytes((Header(self.mac, self.xid).encode(),)) + self.body()

    def describe(self) -> str:
        text = f"{service_name(self.service)} class 0x{self.class_id:02X} instance {self.instance}"
        if self.attribute is not None:
            text += f" attribute {self.attribute}"
        if self.data:
            text += f" data {self.data.hex(' ').upper()}"
        return text


@dataclass(frozen=True, slots=True)
class ExplicitResponse:
    """A success response; ``service`` is the request's service code (the response bit is added on encoding)."""

    mac: int
    service: int
    data: bytes = b""
    xid: int = 0

    def body(self) -> bytes:
        if not 0 <= self.service <= 0x7F or self.service == Service.ERROR_RESPONSE:
            raise EncodeError(f"service 0x{self.service:X} cannot be answered with success", field="service")
        return bytes((self.service | RESPONSE_BIT,)) + bytes(self.data)

    def encode(self) -> bytes:
        return bytes((Header(self.mac, self.xid).encode(),)) + self.body()


@dataclass(frozen=True, slots=True)
class ErrorResponse:
    """An error response: general status and additional status (0xFF = none)."""

    mac: int
    status: CipStatus
    xid: int = 0

    def body(self) -> bytes:
        return bytes(
            (ERROR_SERVICE, _byte("general", self.status.general), _byte("additional", self.status.additional))
        )

    def encode(self) -> bytes:
        return bytes((Header(self.mac, self.xid).encode(),)) + self.body()

    def error(self, service: int | None = None, detail: str = "") -> RemoteDeviceError:
        """The core :class:`~starterbus.core.errors.RemoteDeviceError` this response means."""
        return remote_error(self.status, service, detail, self.encode())


Message = ExplicitRequest | ExplicitResponse | ErrorResponse
Response = ExplicitResponse | ErrorResponse


def _check_unfragmented(message: bytes) -> None:
    if len(message) < 2:
        raise FrameTooShortError(
            f"an explicit message needs a header and a service byte, got {len(message)} byte(s)", message, "message"
        )
    if message[0] & FRAGMENT_BIT:
        raise UnexpectedFrameError("fragment given where a whole message was expected", message, "header")


def is_response(message: bytes) -> bool:
    return len(message) >= 2 and bool(message[1] & RESPONSE_BIT)


def decode_request(message: bytes) -> ExplicitRequest:
    """Decode a whole request (header + body). Any service code decodes; serving it is the server's business."""
    _check_unfragmented(message)
    header = decode_header(message[0])
    if message[1] & RESPONSE_BIT:
        raise UnexpectedFrameError("this is a response, a request was expected", message, "service")
    service = message[1]
    if len(message) < 4:
        raise FrameTooShortError(
            f"{service_name(service)} request needs class and instance bytes, got {len(message)} byte(s)",
            message,
            "path",
        )
    attribute: int | None = None
    rest = 4
    if service in ATTRIBUTE_SERVICES:
        if len(message) < 5:
            raise FrameTooShortError(f"{service_name(service)} request needs an attribute id", message, "attribute")
        attribute = message[4]
        rest = 5
    return ExplicitRequest(header.mac, service, message[2], message[3], attribute, bytes(message[rest:]), header.xid)


def decode_response(message: bytes) -> Response:
    """Decode a whole response (success or error); unknown service codes raise :class:`UnknownServiceError`."""
    _check_unfragmented(message)
    header = decode_header(message[0])
    if not message[1] & RESPONSE_BIT:
        raise UnexpectedFrameError("this is a request, a response was expected", message, "service")
    if message[1] == ERROR_SERVICE:
        if len(message) < 3:
            raise FrameTooShortError("error response without a general status", message, "general_status")
        if len(message) > 4:
            raise FrameTooLongError(
                f"error response with {len(message) - 4} byte(s) after the additional code: "
                f"{message[4:].hex(' ').upper()} (it is [header][94][general status][additional code])",
                message,
                "additional_status",
            )
        additional = message[3] if len(message) > 3 else NO_ADDITIONAL
        return ErrorResponse(header.mac, CipStatus(message[2], additional), header.xid)
    service = message[1] & 0x7F
    if service not in Service._value2member_map_:
        raise UnknownServiceError(f"response with unknown service 0x{service:02X}", message, "service")
    return ExplicitResponse(header.mac, service, bytes(message[2:]), header.xid)


def decode_message(message: bytes) -> Message:
    """A request or a response, by the response bit of the service byte."""
    _check_unfragmented(message)
    return decode_response(message) if message[1] & RESPONSE_BIT else decode_request(message)


def check_response(request: ExplicitRequest, response: Response) -> ExplicitResponse:
    """The success response to ``request``, or raise: an error response becomes a RemoteDeviceError, a
    response of another service or transaction an :class:`UnexpectedFrameError` / :class:`UnknownServiceError`."""
    if response.xid != request.xid:
        raise UnexpectedFrameError(
            f"response transaction id {response.xid} does not match the request's {request.xid}",
            response.encode(),
            "xid",
        )
    if isinstance(response, ErrorResponse):
        raise response.error(request.service, request.describe())
    if response.service != request.service:
        raise UnknownServiceError(
            f"response to {service_name(response.service)} does not answer {service_name(request.service)}",
            response.encode(),
            "service",
        )
    return response
