"""The Modbus RTU frame codec in one import: the messages (:mod:`.messages`: requests, responses, function and
exception codes, frame constants) and their decoding and checks (:mod:`.decoding`).

The package's own modules import from those two directly; this module is the path the rest of the project, the
tests and the benchmarks import the codec by.
"""

from __future__ import annotations

from starterbus.transports.modbus.codec.decoding import (
    check_header,
    check_response,
    decode_register_request,
    decode_request,
    decode_response,
    expected_response_length,
    request_length,
)
from starterbus.transports.modbus.codec.messages import (
    BROADCAST,
    EXCEPTION_BIT,
    EXCEPTION_FRAME_LENGTH,
    MAX_READ_REGISTERS,
    MAX_UNIT,
    MAX_WRITE_REGISTERS,
    READ_REQUEST_LENGTH,
    STANDARD_EXCEPTION_TEXTS,
    WRITE_FRAME_LENGTH,
    AnyRequest,
    ExceptionCode,
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

__all__ = [
    "BROADCAST",
    "EXCEPTION_BIT",
    "EXCEPTION_FRAME_LENGTH",
    "MAX_READ_REGISTERS",
    "MAX_UNIT",
    "MAX_WRITE_REGISTERS",
    "READ_REQUEST_LENGTH",
    "STANDARD_EXCEPTION_TEXTS",
    "WRITE_FRAME_LENGTH",
    "AnyRequest",
    "ExceptionCode",
    "ExceptionResponse",
    "FunctionCode",
    "OtherRequest",
    "ReadInputRequest",
    "ReadInputResponse",
    "ReadRequest",
    "ReadResponse",
    "Request",
    "Response",
    "WriteRegistersRequest",
    "WriteRegistersResponse",
    "WriteRequest",
    "WriteResponse",
    "check_header",
    "check_response",
    "decode_register_request",
    "decode_request",
    "decode_response",
    "expected_response_length",
    "request_length",
]
