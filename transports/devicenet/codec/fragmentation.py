"""The DeviceNet fragmentation protocol for explicit messages longer than 8 bytes, both directions.

Each fragment frame is ``[header | 0x80][type << 6 | count][up to 6 body bytes]`` with type 0 first, 1 middle,
2 last; the count starts at 0 and goes up by one modulo 64. The receiver acknowledges every fragment on its own
transmit identifier with ``[header | 0x80][0xC0 | count][status]`` (status 0 success, 1 too much data), and
the sender waits for that acknowledgement before sending the next fragment.

:class:`Fragmenter` (sender) and :class:`Reassembler` (receiver) are small state machines with no I/O and no
clock: the driver feeds them frame data and sends what they return, and decides about timeouts itself.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from starterbus.core import EncodeError
from starterbus.transports.devicenet.codec.cip import (
    CipStatus,
    FragmentError,
    FrameTooShortError,
    GeneralStatus,
    UnexpectedFrameError,
)
from starterbus.transports.devicenet.codec.explicit import FRAGMENT_BIT, MAX_UNFRAGMENTED

FRAGMENT_PAYLOAD = 6
COUNT_MASK = 0x3F
DEFAULT_MAX_MESSAGE = 1 + 240  # header + body; the JJR8000 never sends more than a few dozen bytes


class FragmentType(enum.IntEnum):
    FIRST = 0
    MIDDLE = 1
    LAST = 2
    ACK = 3


class AckStatus(enum.IntEnum):
    SUCCESS = 0
    TOO_MUCH_DATA = 1


@dataclass(frozen=True, slots=True)
class Fragment:
    """One fragment frame (or an acknowledgement: ``kind`` ACK, ``payload`` = the one status byte)."""

    header: int  # the header byte, fragment bit included
    kind: FragmentType
    count: int
    payload: bytes = b""

    def encode(self) -> bytes:
        if not 0 <= self.count <= COUNT_MASK:
            raise EncodeError(f"fragment count {self.count} is outside 0..63", field="fragment.count")
        if len(self.payload) > FRAGMENT_PAYLOAD:
            raise EncodeError(f"{len(self.payload)} bytes do not fit one fragment (max 6)", self.payload, "fragment")
        return bytes((self.header | FRAGMENT_BIT, (int(self.kind) << 6) | self.count)) + self.payload

    @property
    def is_ack(self) -> bool:
        return self.kind is FragmentType.ACK

    @property
    def ack_status(self) -> int:
        return self.payload[0] if self.payload else 0


def is_fragment(data: bytes) -> bool:
    return len(data) >= 1 and bool(data[0] & FRAGMENT_BIT)


def decode_fragment(data: bytes) -> Fragment:
    if len(data) < 2:
        raise FrameTooShortError(
            f"a fragment needs a header and a fragment byte, got {len(data)} byte(s)", data, "fragment"
        )
    if not data[0] & FRAGMENT_BIT:
        raise UnexpectedFrameError("the header's fragment bit is not set", data, "header")
    kind = FragmentType(data[1] >> 6)
    if kind is FragmentType.ACK:
        if len(data) < 3:
            raise FrameTooShortError("a fragment acknowledgement needs a status byte", data, "ack_status")
        return Fragment(data[0], kind, data[1] & COUNT_MASK, bytes(data[2:3]))
    return Fragment(data[0], kind, data[1] & COUNT_MASK, bytes(data[2:]))


def ack(header: int, count: int, status: AckStatus = AckStatus.SUCCESS) -> bytes:
    """The acknowledgement of fragment ``count`` of a series whose header byte is ``header``."""
    return Fragment(header, FragmentType.ACK, count, bytes((int(status),))).encode()


def split(message: bytes) -> list[bytes]:
    """The fragment frames of a whole message (header + body): 6 body bytes per frame."""
    if len(message) < 2:
        raise EncodeError("a message needs a header and a body", message, "message")
    header = message[0] | FRAGMENT_BIT
    body = message[1:]
    chunks = [body[i : i + FRAGMENT_PAYLOAD] for i in range(0, len(body), FRAGMENT_PAYLOAD)]
    frames = []
    for index, chunk in enumerate(chunks):
        if index == 0:
            kind = FragmentType.FIRST
        elif index == len(chunks) - 1:
            kind = FragmentType.LAST
        else:
            kind = FragmentType.MIDDLE
        frames.append(Fragment(header, kind, index & COUNT_MASK, chunk).encode())
    if len(frames) == 1:  # a one-fragment series still needs an end: send an empty last fragment
        frames.append(Fragment(header, FragmentType.LAST, 1, b"").encode())
    return frames


def frames_for(message: bytes) -> list[bytes]:
    """One frame if the message fits 8 bytes, else its fragments."""
    return [message] if len(message) <= MAX_UNFRAGMENTED else split(message)


class FragmentOverflowError(FragmentError):
    """A fragment series grew beyond the receiver's limit; ``ack`` is the "too much data" acknowledgement."""

    status = CipStatus(GeneralStatus.TOO_MUCH_DATA)

    def __init__(self, message: str, data: bytes, ack_data: bytes) -> None:
        self.ack = ack_data
        super().__init__(message, data, "fragment")


class Fragmenter:
    """Sender side: hands out one fragment, waits for its acknowledgement, then the next.

    ``current`` is the fragment awaiting its acknowledgement (send it again on a timeout); ``on_ack`` returns
    the next fragment to send, or None (stale acknowledgement, or the series is complete: see ``done``).
    """

    def __init__(self, message: bytes) -> None:
        self.frames = split(message)
        self.index = 0
        self.done = False

    @property
    def current(self) -> bytes:
        return self.frames[self.index]

    @property
    def count(self) -> int:
        return self.frames[self.index][1] & COUNT_MASK

    def on_ack(self, data: bytes) -> bytes | None:
        fragment = decode_fragment(data)
        if not fragment.is_ack:
            raise UnexpectedFrameError("expected a fragment acknowledgement", data, "fragment")
        if self.done or fragment.count != self.count:
            return None  # a late duplicate acknowledgement: nothing to do
        if fragment.ack_status != AckStatus.SUCCESS:
            self.done = True
            raise FragmentError(
                f"the receiver refused fragment {fragment.count} with status {fragment.ack_status}"
                + (" (too much data)" if fragment.ack_status == AckStatus.TOO_MUCH_DATA else ""),
                data,
                "ack_status",
                CipStatus(GeneralStatus.TOO_MUCH_DATA),
            )
        if self.index == len(self.frames) - 1:
            self.done = True
            return None
        self.index += 1
        return self.current


class Reassembler:
    """Receiver side: feed fragment frames; each call returns ``(ack to send, whole message or None)``.

    The whole message is returned as one unfragmented message (header with the fragment bit cleared + body).
    A first fragment always starts a new series (an unfinished one is dropped). A repeated fragment (the
    sender missed our acknowledgement) is acknowledged again and not appended. A middle or last fragment out of
    order, or without a first fragment, drops the series and raises :class:`FragmentError` (no
    acknowledgement); a series longer than ``max_message`` raises :class:`FragmentOverflowError` carrying the
    "too much data" acknowledgement.
    """

    def __init__(self, max_message: int = DEFAULT_MAX_MESSAGE) -> None:
        self.max_message = max_message
        self._header: int | None = None
        self._count = 0
        self._body = bytearray()

    @property
    def in_progress(self) -> bool:
        return self._header is not None

    def reset(self) -> None:
        self._header = None
        self._count = 0
        self._body.clear()

    def feed(self, data: bytes) -> tuple[bytes, bytes | None]:
        fragment = decode_fragment(data)
        if fragment.is_ack:
            raise UnexpectedFrameError("an acknowledgement is not a fragment of a message", data, "fragment")
        if fragment.kind is FragmentType.FIRST:
            self.reset()
            self._header = fragment.header
            self._count = fragment.count
            return self._append(fragment, data)
        if self._header is None:
            raise FragmentError(
                f"{fragment.kind.name.lower()} fragment {fragment.count} without a first fragment", data, "fragment"
            )
        if fragment.header != self._header:
            self.reset()
            raise FragmentError("fragment of another transaction (header byte changed)", data, "header")
        if fragment.count == self._count:
            return ack(fragment.header, fragment.count), None  # repeated: acknowledge again, do not append
        expected = (self._count + 1) & COUNT_MASK
        if fragment.count != expected:
            self.reset()
            raise FragmentError(f"fragment {fragment.count} out of order (expected {expected})", data, "fragment.count")
        self._count = fragment.count
        return self._append(fragment, data)

    def _append(self, fragment: Fragment, data: bytes) -> tuple[bytes, bytes | None]:
        if 1 + len(self._body) + len(fragment.payload) > self.max_message:
            self.reset()
            raise FragmentOverflowError(
                f"fragmented message longer than {self.max_message} bytes",
                data,
                ack(fragment.header, fragment.count, AckStatus.TOO_MUCH_DATA),
            )
        self._body += fragment.payload
        reply = ack(fragment.header, fragment.count)
        if fragment.kind is FragmentType.LAST:
            message = bytes((fragment.header & ~FRAGMENT_BIT & 0xFF,)) + bytes(self._body)
            self.reset()
            return reply, message
        return reply, None
