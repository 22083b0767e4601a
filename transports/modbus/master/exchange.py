"""A request made ready to send, and the rules of one transaction (bounded waiting and retrying).

Sans-IO: an :class:`Exchange` encodes the request once, knows the exact length of a normal answer and decodes a
whole good answer with as little work as possible; the line driver (``line.py``) moves the bytes.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from starterbus.core import StarterbusError, TimeoutError
from starterbus.transports.modbus.codec.crc import crc16
from starterbus.transports.modbus.codec.decoding import expected_response_length
from starterbus.transports.modbus.codec.messages import (
    BROADCAST,
    EXCEPTION_FRAME_LENGTH,
    ReadRequest,
    ReadResponse,
    Request,
    Response,
    WriteRegistersRequest,
    WriteRegistersResponse,
    WriteResponse,
)


@dataclass(frozen=True, slots=True)
class TransactionPolicy:
    """Per-device rules for one transaction: bounded waiting and retrying.

    ``quarantine``: after a failed attempt (timeout, bad frame, garbage, suspect answer) the line must stay
    silent this long before the next request (0: the response timeout, which is also the minimum).
    """

    timeout: float = 0.5
    retries: int = 2
    retry_writes: bool = False
    turnaround: float = 0.1  # after a broadcast: time the slaves get before the next request
    quarantine: float = 0.0


class Exchange:
    """One request made ready once and sent by every transaction that asks for it (callers may cache it).

    Holds the frame, the length of a normal answer, the attempts and time the policy allows, and decodes an
    answer that arrived whole and right with as little work as possible (:meth:`quick_decode`). Anything else
    (an exception, a piece, garbage, a bad CRC) goes to a :class:`ResponseReceiver`, which gives the typed error.
    """

    __slots__ = (
        "answer_length", "attempts", "broadcast", "budget", "frame", "frame_length", "header_length", "last",
        "may_retry", "policy", "prefix", "prefix_crc", "quarantine", "quiet_limit", "request", "wire", "words",
    )  # fmt: skip

    def __init__(self, request: Request, policy: TransactionPolicy, char_time: float) -> None:
        self.request = request
        self.policy = policy
        self.frame = request.encode()
        self.frame_length = len(self.frame)
        self.broadcast = request.unit == BROADCAST
        self.answer_length = expected_response_length(request)
        self.header_length = min(EXCEPTION_FRAME_LENGTH, self.answer_length)  # an exception is complete by then
        self.may_retry = isinstance(request, ReadRequest) or policy.retry_writes
        self.attempts = 1 + (policy.retries if self.may_retry else 0)
        self.quarantine = max(policy.quarantine, policy.timeout)
        #: how long a send may wait for the line to fall silent (each stray byte restarts a quarantine)
        self.quiet_limit = max(1.0, 4 * self.quarantine)
        self.wire = len(self.frame) * char_time
        # once the request is written: its wire time, the device's timeout, then the answer's wire time
        self.budget = self.wire + policy.timeout + self.answer_length * char_time
        self.words: struct.Struct | None = None  # how to unpack the registers of an FC03 answer
        #: the last good answer and its decoding: an answer with the same bytes is the same answer
        self.last: tuple[bytes, Response | None] = (b"", None)
        if isinstance(request, ReadRequest):
            self.prefix = bytes((request.unit, request.function, 2 * request.count))
            self.prefix_crc = crc16(self.prefix)  # the CRC check of an answer starts after its known header
            if request.function == ReadRequest.function:  # FC04 (a gateway's, over MBAP): the full decoder
                self.words = struct.Struct(f">{request.count}H")
        elif isinstance(request, WriteRegistersRequest):
            self.prefix = self.frame[:6]  # a good FC16 answer: unit, function, address, count of the request
            self.prefix_crc = 0  # unused: a good answer is the one below, compared whole
            answer = WriteRegistersResponse(request.unit, request.address, len(request.values))
            self.last = (answer.encode(), answer)
        else:
            self.prefix = self.frame  # a good FC06 answer is the request, byte for byte
            self.prefix_crc = 0  # unused: the echo is compared whole
            self.last = (self.frame, WriteResponse(request.unit, request.address, request.value))

    def no_answer(self, line: str) -> TimeoutError:
        """No answer on ``line`` within the policy's timeout (either driver's words)."""
        return TimeoutError(
            f"{line}: no answer from unit {self.request.unit} within {self.policy.timeout:g} s to "
            f"{self.frame.hex(' ').upper()}"
        )

    def last_attempt(self, exc: StarterbusError, attempt: int) -> bool:
        """Whether attempt ``attempt`` that failed with ``exc`` was the last the policy allows; if so, ``exc`` says
        so (``(attempt 2 of 2)``, and why a write was not repeated)."""
        attempts = self.attempts
        if attempt < attempts:
            return False
        note = f" (attempt {attempt} of {attempts}"
        note += ")" if self.may_retry else "; a write is not repeated unless retry_writes=1)"
        exc.args = (str(exc) + note,)
        return True

    def good_so_far(self, data: bytes) -> bool:
        """True if ``data`` (at least the header) is how a normal answer to the request begins."""
        return self.prefix.startswith(data[: len(self.prefix)])

    def quick_decode(self, data: bytes) -> Response | None:
        """The answer if ``data`` is exactly a well-formed normal answer to the request, else None.

        Equivalent to the full decoder on such frames (unit, function, byte count, length, CRC, echo all
        compared at once); None sends the bytes to the :class:`ResponseReceiver`, which names what is wrong.
        The same bytes as the last good answer (a register that did not change, every FC06 echo) are that
        answer again, without a second CRC.
        """
        last_frame, last_response = self.last
        if data == last_frame:
            return last_response
        if self.words is None or len(data) != self.answer_length or not data.startswith(self.prefix):
            return None
        # the CRC over a frame and its own CRC (low byte first) is 0 exactly when the CRC is right;
        # the part for the 3-byte prefix is computed once
        if crc16(data[3:], self.prefix_crc) != 0:
            return None
        response = ReadResponse.from_words(self.request.unit, self.words.unpack_from(data, 3))
        self.last = (data, response)  # one assignment: another thread sees the old pair or the new one
        return response
