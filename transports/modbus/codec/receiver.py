"""Incremental receivers: feed bytes as they arrive, get a frame, "need more" or a typed error.

:class:`ResponseReceiver` is the master's side. It knows the length of the answer from the request, so a
reader asks :meth:`~ResponseReceiver.bytes_needed` how much to read and stops at the last byte instead of
waiting for a silent interval: first the 5-byte header (which is already a whole exception frame), then the
rest. Unit and function are checked as soon as the header is in, so garbage is reported without waiting.

:class:`RequestReceiver` is the slave's side: request lengths follow from the function code; a request whose
length the header cannot tell (an unsupported function code) ends at the next silent interval, which the I/O
driver reports with :meth:`~RequestReceiver.end_of_frame`.

Neither does any I/O or looks at a clock (sans-IO, like h11).
"""

from __future__ import annotations

import enum

from starterbus.core import DecodeError
from starterbus.transports.modbus.codec.decoding import (
    check_header,
    decode_request,
    decode_response,
    expected_response_length,
    request_length,
)
from starterbus.transports.modbus.codec.messages import (
    EXCEPTION_BIT,
    EXCEPTION_FRAME_LENGTH,
    AnyRequest,
    ReadRequest,
    Request,
    Response,
)


class NeedData(enum.Enum):
    """The bytes so far are the beginning of a frame; read more."""

    NEED_DATA = "need data"


NEED_DATA = NeedData.NEED_DATA


class ResponseReceiver:
    """Collects the answer to one request. After a frame or an error it does not take a second one."""

    def __init__(self, request: Request, *, crc: bool = True) -> None:
        self.request = request
        self.crc = crc
        self.expected_length = expected_response_length(request)
        self._buffer = bytearray()
        self._length: int | None = None  # known once the header is in
        self._result: Response | None = None
        self._error: DecodeError | None = None

    def feed(self, data: bytes | bytearray | memoryview) -> None:
        self._buffer += data

    @property
    def received(self) -> bytes:
        """Every byte fed so far."""
        return bytes(self._buffer)

    @property
    def frame(self) -> bytes:
        """The bytes of the answer (so far, or complete once :meth:`next_event` returned it)."""
        if self._length is None:
            return bytes(self._buffer)
        return bytes(self._buffer[: self._length])

    @property
    def trailing(self) -> bytes:
        """Bytes fed after the end of the answer."""
        if self._length is None:
            return b""
        return bytes(self._buffer[self._length :])

    def bytes_needed(self) -> int:
        """How many more bytes to read before :meth:`next_event` can say more (0: it can now)."""
        if self._result is not None or self._error is not None:
            return 0
        if self._length is None:
            header = min(EXCEPTION_FRAME_LENGTH, self.expected_length)
            return max(0, header - len(self._buffer))
        return max(0, self._length - len(self._buffer))

    def _fail(self, error: DecodeError) -> DecodeError:
        self._error = error
        return error

    def next_event(self) -> Response | NeedData:
        """The decoded answer, or NEED_DATA; raises :class:`DecodeError` (e.g. ChecksumError) for bad bytes."""
        if self._error is not None:
            raise self._error
        if self._result is not None:
            return self._result
        buf = self._buffer
        if self._length is None:
            if len(buf) < 2:
                return NEED_DATA
            try:
                check_header(self.request, bytes(buf[: min(len(buf), EXCEPTION_FRAME_LENGTH)]))
            except DecodeError as exc:
                raise self._fail(exc) from None
            if buf[1] & EXCEPTION_BIT:
                self._length = EXCEPTION_FRAME_LENGTH
            elif isinstance(self.request, ReadRequest):
                if len(buf) < 3:
                    return NEED_DATA
                count = buf[2]
                if count != 2 * self.request.count:
                    raise self._fail(
                        DecodeError(
                            f"byte count {count} does not announce the {self.request.count} registers requested",
                            bytes(buf[: min(len(buf), EXCEPTION_FRAME_LENGTH)]),
                            "byte_count",
                        )
                    )
                self._length = self.expected_length
            else:
                self._length = self.expected_length
        if len(buf) < self._length:
            return NEED_DATA
        try:
            self._result = decode_response(bytes(buf[: self._length]), crc=self.crc, request=self.request)
        except DecodeError as exc:
            raise self._fail(exc) from None
        return self._result

    def truncated_error(self) -> DecodeError:
        """The error for a frame that stopped before its end (the line went silent or the time ran out)."""
        have = len(self._buffer)
        want = self._length if self._length is not None else self.expected_length
        return DecodeError(f"truncated answer: {have} of {want} bytes arrived", bytes(self._buffer), "length")


class RequestReceiver:
    """Splits a slave's input into request frames; keeps going after errors (the driver skips to silence)."""

    def __init__(self, *, crc: bool = True) -> None:
        self.crc = crc
        self._buffer = bytearray()

    def feed(self, data: bytes | bytearray | memoryview) -> None:
        self._buffer += data

    @property
    def pending(self) -> bytes:
        return bytes(self._buffer)

    def reset(self) -> bytes:
        """Forget the buffered bytes (after an error, at the next silent interval); returns them."""
        dropped = bytes(self._buffer)
        self._buffer.clear()
        return dropped

    def bytes_needed(self) -> int | None:
        """Bytes still missing from the current frame; None if only a silent interval can end it."""
        if len(self._buffer) < 2:
            return 2 - len(self._buffer)
        length = request_length(bytes(self._buffer[:11]))
        if length is None:
            return None
        return max(0, length - len(self._buffer))

    def next_event(self) -> AnyRequest | NeedData:
        """The next complete request, or NEED_DATA. Raises DecodeError and drops that frame's bytes."""
        if len(self._buffer) < 2:
            return NEED_DATA
        length = request_length(bytes(self._buffer[:11]))
        if length is None or len(self._buffer) < length:
            return NEED_DATA
        frame = bytes(self._buffer[:length])
        del self._buffer[:length]
        return decode_request(frame, crc=self.crc)

    def end_of_frame(self) -> AnyRequest | None:
        """The line went silent: the buffered bytes are one frame (or garbage). Clears the buffer.

        Returns the request, None if nothing was buffered; raises DecodeError for a truncated or bad frame.
        """
        frame = self.reset()
        if not frame:
            return None
        length = request_length(frame[:11])
        if length is not None and len(frame) < length:
            raise DecodeError(f"truncated request: {len(frame)} of {length} bytes", frame, "length")
        return decode_request(frame, crc=self.crc)
