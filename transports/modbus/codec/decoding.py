"""Whole Modbus RTU frames -> messages (:mod:`.messages`), answers checked against their requests, frame lengths.

Pure functions, no I/O: :func:`decode_request` / :func:`decode_response` take a whole frame and either return a
value or raise a :class:`~starterbus.core.errors.DecodeError` (or :class:`ChecksumError`) naming the bytes.
Checking an answer against the request it answers (unit, function, byte count, FC06 echo) is
:func:`check_response`.
"""

from __future__ import annotations

from starterbus.core import DecodeError
from starterbus.transports.modbus.codec.crc import CRC_LENGTH, strip_crc
from starterbus.transports.modbus.codec.messages import (
    EXCEPTION_BIT,
    WRITE_FRAME_LENGTH,
    AnyRequest,
    ExceptionResponse,
    FunctionCode,
    OtherRequest,
    ReadInputRequest,
    ReadInputResponse,
    ReadRequest,
    ReadResponse,
    Request,
    Response,
    WriteRegistersRequest,
    WriteRegistersResponse,
    WriteRequest,
    WriteResponse,
)

_READS: dict[int, type[ReadResponse]] = {
    FunctionCode.READ_HOLDING_REGISTERS: ReadResponse,
    FunctionCode.READ_INPUT_REGISTERS: ReadInputResponse,
}


# -- lengths ------------------------------------------------------------------------------------------------


def expected_response_length(request: Request) -> int:
    """Length of the normal answer to ``request``: FC03/FC04 -> 5 + 2n, FC06 and FC16 -> 8 (an exception is 5)."""
    if isinstance(request, ReadRequest):
        return 5 + 2 * request.count
    return WRITE_FRAME_LENGTH


#: request frame lengths by function code, where the header alone fixes it (Modbus application protocol)
_FIXED_REQUEST_LENGTHS = {
    0x01: 8, 0x02: 8, 0x03: 8, 0x04: 8, 0x05: 8, 0x06: 8, 0x07: 4, 0x08: 8, 0x0B: 4, 0x0C: 4, 0x11: 4, 0x16: 10,
}  # fmt: skip
#: function code -> (offset of its byte count, bytes before the counted data) for variable-length requests
_COUNTED_REQUESTS = {0x0F: (6, 7), 0x10: (6, 7), 0x17: (10, 11)}


def request_length(header: bytes) -> int | None:
    """Length of a request frame from its first bytes; None if these bytes cannot tell (yet or ever).

    A slave that gets None for a complete header (unknown function code) delimits the frame by silence.
    """
    if len(header) < 2:
        return None
    function = header[1]
    fixed = _FIXED_REQUEST_LENGTHS.get(function)
    if fixed is not None:
        return fixed
    counted = _COUNTED_REQUESTS.get(function)
    if counted is not None:
        offset, before = counted
        if len(header) <= offset:
            return None
        return before + header[offset] + CRC_LENGTH
    return None


# -- decoding -----------------------------------------------------------------------------------------------


def _body(frame: bytes, crc: bool) -> bytes:
    data = bytes(frame)
    body = strip_crc(data) if crc else data
    if len(body) < 2:
        raise DecodeError("a frame needs at least a unit id and a function code", data, "frame")
    return body


def decode_request(frame: bytes, *, crc: bool = True) -> AnyRequest:
    """A whole request frame -> request. ``crc=False`` for frames printed without CRC (JJR8000 manual)."""
    data = bytes(frame)
    body = _body(data, crc)
    unit, function = body[0], body[1]
    if function & EXCEPTION_BIT:
        raise DecodeError(f"function code {function:#04x} has the exception bit: not a request", data, "function")
    if function == 0:
        raise DecodeError("function code 0x00 is not a Modbus function", data, "function")
    if function in (FunctionCode.READ_HOLDING_REGISTERS, FunctionCode.WRITE_SINGLE_REGISTER):
        if len(body) != 6:
            raise DecodeError(
                f"a FC{function:02X} request has 6 bytes before the CRC, this one {len(body)}", data, "length"
            )
        address = int.from_bytes(body[2:4], "big")
        word = int.from_bytes(body[4:6], "big")
        if function == FunctionCode.READ_HOLDING_REGISTERS:
            return ReadRequest(unit, address, word)
        return WriteRequest(unit, address, word)
    return OtherRequest(unit, function, body[2:])


def decode_register_request(frame: bytes, *, crc: bool = True) -> ReadRequest | WriteRegistersRequest:
    """A whole FC03, FC04 or FC16 request frame (what a register gateway serves) -> request; anything else a
    :class:`DecodeError`. (:func:`decode_request` is what the starters take: FC04 and FC16 are other requests.)"""
    data = bytes(frame)
    body = _body(data, crc)
    unit, function = body[0], body[1]
    if function in _READS:
        if len(body) != 6:
            raise DecodeError(
                f"a FC{function:02d} request has 6 bytes before the CRC, this one {len(body)}", data, "length"
            )
        read = ReadRequest if function == FunctionCode.READ_HOLDING_REGISTERS else ReadInputRequest
        return read(unit, int.from_bytes(body[2:4], "big"), int.from_bytes(body[4:6], "big"))
    if function != FunctionCode.WRITE_MULTIPLE_REGISTERS:
        raise DecodeError(f"function code {function:#04x} is not FC03, FC04 or FC16", data, "function")
    count = int.from_bytes(body[4:6], "big") if len(body) >= 6 else -1
    if len(body) < 7 or body[6] != 2 * count or len(body) != 7 + 2 * count:
        raise DecodeError(
            f"a FC16 request of {count} registers has {7 + 2 * count} bytes before the CRC (byte count {2 * count}), "
            f"this one {len(body)}",
            data,
            "length",
        )
    values = tuple(int.from_bytes(body[i : i + 2], "big") for i in range(7, 7 + 2 * count, 2))
    return WriteRegistersRequest(unit, int.from_bytes(body[2:4], "big"), values)


def _registers(data: bytes, body: bytes, function: int) -> tuple[int, ...]:
    """The register values of a FC03/FC04 answer's body."""
    if len(body) < 3:
        raise DecodeError(f"a FC{function:02d} response needs a byte count", data, "byte_count")
    count = body[2]
    if count == 0 or count % 2:
        raise DecodeError(f"byte count {count} is not an even number of register bytes", data, "byte_count")
    if len(body) != 3 + count:
        raise DecodeError(
            f"byte count {count} announces {3 + count} bytes before the CRC, this one has {len(body)}",
            data,
            "length",
        )
    return tuple(int.from_bytes(body[i : i + 2], "big") for i in range(3, 3 + count, 2))


def decode_response(frame: bytes, *, crc: bool = True, request: Request | None = None) -> Response:
    """A whole response frame -> response; with ``request``, also checked as the answer to it."""
    data = bytes(frame)
    if request is not None and len(data) >= 2:
        check_header(request, data)
    body = _body(data, crc)
    unit, function = body[0], body[1]
    response: Response
    if function & EXCEPTION_BIT:
        if len(body) != 3:
            raise DecodeError(
                f"an exception response has 3 bytes before the CRC, this one {len(body)}",
                data,
                "length",
            )
        response = ExceptionResponse(unit, function & ~EXCEPTION_BIT, body[2])
    elif function in _READS:
        response = _READS[function].from_words(unit, _registers(data, body, function))
    elif function == FunctionCode.WRITE_SINGLE_REGISTER:
        if len(body) != 6:
            raise DecodeError(
                f"a FC06 response echoes the request: 6 bytes before the CRC, this one has {len(body)}",
                data,
                "length",
            )
        response = WriteResponse(unit, int.from_bytes(body[2:4], "big"), int.from_bytes(body[4:6], "big"))
    elif function == FunctionCode.WRITE_MULTIPLE_REGISTERS:
        if len(body) != 6:
            raise DecodeError(
                f"a FC16 response has 6 bytes before the CRC (address, count), this one has {len(body)}", data, "length"
            )
        response = WriteRegistersResponse(unit, int.from_bytes(body[2:4], "big"), int.from_bytes(body[4:6], "big"))
    else:
        raise DecodeError(f"function code {function:#04x} is not one these devices answer with", data, "function")
    if request is not None:
        check_response(request, response, data)
    return response


def check_header(request: Request, data: bytes) -> None:
    """Unit and function of an answer, checkable from its first two bytes."""
    unit, function = data[0], data[1]
    if unit != request.unit:
        raise DecodeError(f"answer from unit {unit}, the request went to unit {request.unit}", data, "unit")
    if function not in (request.function, request.function | EXCEPTION_BIT):
        raise DecodeError(
            f"function code {function:#04x} does not answer a FC{request.function:02d} request", data, "function"
        )


def check_response(request: Request, response: Response, data: bytes = b"") -> None:
    """Raise :class:`DecodeError` unless ``response`` is a well-formed answer to ``request``."""
    if response.unit != request.unit:
        raise DecodeError(f"answer from unit {response.unit}, the request went to unit {request.unit}", data, "unit")
    if isinstance(response, ExceptionResponse):
        if response.function != request.function:
            raise DecodeError(
                f"exception for FC{response.function:02d} does not answer a FC{request.function:02d} request",
                data,
                "function",
            )
        return
    if response.function != request.function:
        raise DecodeError(
            f"FC{response.function:02d} response does not answer a FC{request.function:02d} request", data, "function"
        )
    if isinstance(request, ReadRequest):
        assert isinstance(response, ReadResponse)
        if len(response.values) != request.count:
            raise DecodeError(
                f"{len(response.values)} registers returned, {request.count} requested", data, "byte_count"
            )
        return
    if isinstance(request, WriteRegistersRequest):
        assert isinstance(response, WriteRegistersResponse)
        if (response.address, response.count) != (request.address, len(request.values)):
            raise DecodeError(
                f"not the answer to the write of {len(request.values)} registers at {request.address:#06x}: "
                f"got {response.count} at {response.address:#06x}",
                data,
                "echo",
            )
        return
    assert isinstance(response, WriteResponse)
    if (response.address, response.value) != (request.address, request.value):
        raise DecodeError(
            f"not an echo of the write ({request.address:#06x} = {request.value:#06x}): "
            f"got {response.address:#06x} = {response.value:#06x}",
            data,
            "echo",
        )
