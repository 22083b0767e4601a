"""One RTU line (a serial port, or a TCP connection to a serial device server) and its transactions.

A :class:`RtuLine` is shared by every device on it in one process (through a :class:`SharedPool`); its lock
makes one request + answer at a time, whatever thread asks. It keeps the 3.5-character silent interval by
remembering when the line was last busy, reads exactly the length the request predicts (the 5-byte header
first, which is a whole frame for an exception), and retries within the policy it is given.
"""

from __future__ import annotations

import functools
import os
import select
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from starterbus.core.errors import ConfigurationError, DecodeError, TimeoutError, TransportError
from starterbus.transports.modbus.crc import crc16
from starterbus.transports.modbus.frames import (
    BROADCAST,
    EXCEPTION_FRAME_LENGTH,
    ReadRequest,
    ReadResponse,
    Request,
    Response,
    WriteResponse,
    expected_response_length,
)
from starterbus.transports.modbus.receiver import NEED_DATA, ResponseReceiver
from starterbus.transports.modbus.timing import char_time

_READ_CHUNK = 512
_NOTHING: tuple[int, ...] = ()  # the empty write and error sets of select.select


@dataclass(frozen=True, slots=True)
class SerialSettings:
    """How the UART frames characters; ``silence`` is the interval kept between frames, in seconds."""

    baudrate: int = 9600
    parity: str = "N"
    stopbits: int = 1
    bytesize: int = 8
    silence: float = 0.0

    def describe(self) -> str:
        return f"{self.baudrate} {self.bytesize}{self.parity}{self.stopbits}"


@dataclass(frozen=True, slots=True)
class TransactionPolicy:
    """Per-device rules for one transaction: bounded waiting and retrying."""

    timeout: float = 0.5
    retries: int = 2
    retry_writes: bool = False
    turnaround: float = 0.1  # after a broadcast: time the slaves get before the next request


class Link:
    """Bytes in and out of one file descriptor (serial port, pty, socket) with deadlines, never polling."""

    def __init__(
        self,
        fd: int,
        name: str,
        read: Callable[[int], bytes],
        write: Callable[[bytes | memoryview], int],
        close: Callable[[], None],
    ) -> None:
        self.fd = fd
        self.name = name
        self._read = read
        self._write = write
        self._close = close
        self._fds = [fd]  # select's read set, built once
        self.closed = False

    @classmethod
    def open_serial(cls, path: str, settings: SerialSettings) -> Link:
        import termios

        import serial

        try:
            port = serial.Serial(
                port=path,
                baudrate=settings.baudrate,
                bytesize=settings.bytesize,
                parity=settings.parity,
                stopbits=settings.stopbits,
                timeout=0,
                exclusive=True,
            )
        except (serial.SerialException, ValueError, OSError, termios.error) as exc:
            raise TransportError(f"cannot open serial port {path} ({settings.describe()}): {exc}") from exc
        try:
            fd = port.fileno()
        except Exception as exc:
            port.close()
            raise TransportError(f"{path}: the serial port gives no file descriptor (POSIX only): {exc}") from exc
        return cls(fd, path, functools.partial(os.read, fd), functools.partial(os.write, fd), port.close)

    @classmethod
    def connect_tcp(cls, host: str, port: int, timeout: float) -> Link:
        try:
            sock = socket.create_connection((host, port), timeout=timeout)
        except OSError as exc:
            raise TransportError(f"cannot connect to {host}:{port}: {exc}") from exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(False)
        return cls(sock.fileno(), f"{host}:{port}", sock.recv, sock.send, sock.close)

    def _fail(self, what: str, exc: BaseException) -> TransportError:
        return TransportError(f"{self.name}: {what} failed: {exc}")

    def write(self, data: bytes) -> None:
        try:
            sent = self._write(data)
        except BlockingIOError:
            sent = 0
        except OSError as exc:
            raise self._fail("write", exc) from exc
        if sent < len(data):
            self._write_rest(memoryview(data)[sent:])

    def _write_rest(self, view: memoryview) -> None:
        while view:
            try:
                sent = self._write(view)
            except BlockingIOError:
                select.select([], [self.fd], [], 1.0)
                continue
            except OSError as exc:
                raise self._fail("write", exc) from exc
            view = view[sent:]

    def read(self, size: int, deadline: float, limit: int = 0, wait: float | None = None) -> bytes:
        """At least ``size`` bytes (fewer only when ``deadline``, monotonic, has passed), and no more than
        ``limit`` (default ``size``): what has already arrived beyond ``size`` is taken in the same call.

        ``wait``: ``deadline`` minus now, when the caller has just read the clock (saves reading it again).
        """
        limit = max(size, limit)
        out = b""
        while len(out) < size:
            if wait is None:
                wait = deadline - time.monotonic()
            if wait <= 0 or not select.select(self._fds, _NOTHING, _NOTHING, wait)[0]:
                break
            wait = None
            try:  # as _recv, inline: this is every transaction's read
                chunk = self._read(limit - len(out))
            except BlockingIOError:
                continue
            except OSError as exc:
                raise self._fail("read", exc) from exc
            if not chunk:
                raise self._hung_up()
            out += chunk
        return out

    def _recv(self, size: int) -> bytes | None:
        try:
            chunk = self._read(size)
        except BlockingIOError:
            return None
        except OSError as exc:
            raise self._fail("read", exc) from exc
        if not chunk:
            raise self._hung_up()
        return chunk

    def _hung_up(self) -> TransportError:
        return TransportError(f"{self.name}: the other end closed the connection")

    def wait_readable(self, timeout: float) -> bool:
        """True as soon as bytes are there to read; False after ``timeout`` seconds of nothing."""
        return bool(select.select(self._fds, _NOTHING, _NOTHING, max(0.0, timeout))[0])

    def drain(self, quiet: float, limit: float) -> tuple[bytes, float | None]:
        """Read and drop bytes until none came for ``quiet`` seconds, or until ``limit`` (monotonic).

        Returns the dropped bytes and when the last of them arrived (None if none did).
        """
        dropped = b""
        last: float | None = None
        while True:
            now = time.monotonic()
            wait = min(quiet, limit - now)
            if wait <= 0:
                return dropped, last
            if not select.select(self._fds, _NOTHING, _NOTHING, wait)[0]:
                return dropped, last
            chunk = self._recv(_READ_CHUNK)
            if chunk:
                dropped += chunk
                last = time.monotonic()

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._close()


class Exchange:
    """One request made ready once and sent by every transaction that asks for it (callers may cache it).

    Holds the frame, the length of a normal answer, the attempts and time the policy allows, and decodes an
    answer that arrived whole and right with as little work as possible (:meth:`quick_decode`). Anything else
    (an exception, a piece, garbage, a bad CRC) goes to a :class:`ResponseReceiver`, which gives the typed error.
    """

    __slots__ = (
        "answer_length", "attempts", "broadcast", "budget", "frame", "header_length", "last", "may_retry",
        "policy", "prefix", "prefix_crc", "quiet_limit", "request", "wire", "words",
    )  # fmt: skip

    def __init__(self, request: Request, policy: TransactionPolicy, char_time: float) -> None:
        self.request = request
        self.policy = policy
        self.frame = request.encode()
        self.broadcast = request.unit == BROADCAST
        self.answer_length = expected_response_length(request)
        self.header_length = min(EXCEPTION_FRAME_LENGTH, self.answer_length)  # an exception is complete by then
        self.may_retry = isinstance(request, ReadRequest) or policy.retry_writes
        self.attempts = 1 + (policy.retries if self.may_retry else 0)
        self.quiet_limit = max(1.0, policy.timeout)
        self.wire = len(self.frame) * char_time
        # once the request is written: its wire time, the device's timeout, then the answer's wire time
        self.budget = self.wire + policy.timeout + self.answer_length * char_time
        self.words: struct.Struct | None = None  # how to unpack the registers of an FC03 answer
        #: the last good answer and its decoding: an answer with the same bytes is the same answer
        self.last: tuple[bytes, Response | None] = (b"", None)
        if isinstance(request, ReadRequest):
            self.prefix = bytes((request.unit, request.function, 2 * request.count))
            self.prefix_crc = crc16(self.prefix)  # the CRC check of an answer starts after its known header
            self.words = struct.Struct(f">{request.count}H")
        else:
            self.prefix = self.frame  # a good FC06 answer is the request, byte for byte
            self.prefix_crc = 0  # unused: the echo is compared whole
            self.last = (self.frame, WriteResponse(request.unit, request.address, request.value))

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


class RtuLine:
    """One line, shared by every device on it in this process. Thread-safe; one transaction at a time."""

    def __init__(self, connect: Callable[[], Link], settings: SerialSettings) -> None:
        self._connect = connect
        self.link = connect()
        self._name = self.link.name
        self._broken = False  # a transport error: reopen the port / reconnect before the next transaction
        self._closed = False
        self.settings = settings
        self.lock = threading.Lock()
        self.char_time = char_time(settings.baudrate)
        self._silence = settings.silence
        self._quiet_at = 0.0  # monotonic time from which the next frame may start
        self.transactions = 0
        self.retries = 0

    @property
    def name(self) -> str:
        return self._name

    def check_settings(self, settings: SerialSettings) -> None:
        if settings != self.settings:
            raise ConfigurationError(
                f"{self.name} is already open in this process with {self.settings.describe()} "
                f"(silence {self.settings.silence * 1000:.2f} ms); a second device on the line asks for "
                f"{settings.describe()} (silence {settings.silence * 1000:.2f} ms): one line has one setting"
            )

    def close(self) -> None:
        with self.lock:
            self._closed = True
            self.link.close()

    def _usable_link(self) -> Link:
        """The link, reopened (serial) or reconnected (TCP) if a transport error broke it."""
        if self._closed:
            raise TransportError(f"{self.name} is closed")
        if self._broken:
            self.link.close()
            self.link = self._connect()
            self._broken = False
            self._quiet_at = 0.0
        return self.link

    def _wait_quiet(self, limit: float) -> None:
        """Wait until the line has been silent for the interval; bytes arriving meanwhile (a late answer to an
        earlier request, noise) are dropped and restart the interval. Gives up after ``limit`` seconds."""
        now = time.monotonic()
        if self.link.wait_readable(self._quiet_at - now):
            self._drop_until_quiet(now + limit, limit)

    def _drop_until_quiet(self, give_up: float, limit: float) -> None:
        while True:
            dropped, last = self.link.drain(self._silence, give_up)
            self._quiet_at = (last if last is not None else time.monotonic()) + self._silence
            if time.monotonic() >= give_up:
                raise TransportError(
                    f"{self.name}: the line did not fall silent within {limit:g} s "
                    f"(last bytes {dropped[-16:].hex(' ').upper()})"
                )
            if not self.link.wait_readable(self._quiet_at - time.monotonic()):
                return

    def prepare(self, request: Request, policy: TransactionPolicy) -> Exchange:
        """``request`` made ready for :meth:`run` (encoded and checked: an invalid request raises here)."""
        return Exchange(request, policy, self.char_time)

    def transact(self, request: Request, policy: TransactionPolicy) -> Response | None:
        """Send ``request`` and return the checked answer (an ExceptionResponse is an answer, not an error).

        Broadcasts return None. Raises TimeoutError / DecodeError after the allowed attempts: reads are
        retried ``policy.retries`` times; a write only if ``policy.retry_writes`` (it may have been executed).
        """
        return self.run(self.prepare(request, policy))

    def run(self, exchange: Exchange) -> Response | None:
        """:meth:`transact` for a prepared request (the same exchange may be run any number of times)."""
        with self.lock:
            if self._broken or self._closed:
                self._usable_link()
            self.transactions += 1
            try:
                return self._attempts(exchange)
            except TransportError as exc:
                if not isinstance(exc, TimeoutError):
                    self._broken = True  # the next transaction reopens / reconnects
                raise

    def _attempts(self, exchange: Exchange) -> Response | None:
        attempts = exchange.attempts
        for attempt in range(1, attempts + 1):
            self._wait_quiet(exchange.quiet_limit)
            self.link.write(exchange.frame)
            sent_at = time.monotonic()
            if exchange.broadcast:
                self._quiet_at = sent_at + exchange.wire + max(exchange.policy.turnaround, self._silence)
                return None
            try:
                return self._receive(exchange, sent_at)
            except (TimeoutError, DecodeError) as exc:
                self._resync(exchange.policy)
                if attempt == attempts:
                    note = f" (attempt {attempt} of {attempts}"
                    note += ")" if exchange.may_retry else "; a write is not repeated unless retry_writes=1)"
                    exc.args = (str(exc) + note,)
                    raise
                self.retries += 1
        raise AssertionError("unreachable")  # pragma: no cover

    def _receive(self, exchange: Exchange, sent_at: float) -> Response:
        """The answer: at least the header and at most the whole answer in the first read (on a pty, usually
        all of it); the rest of a normal answer in one more read. Anything unusual goes to the receiver."""
        deadline = sent_at + exchange.budget
        needed, length = exchange.header_length, exchange.answer_length
        data = self.link.read(needed, deadline, length, wait=exchange.budget)
        received_at = time.monotonic()
        if needed <= len(data) < length and exchange.good_so_far(data):
            rest = self.link.read(length - len(data), deadline)
            if rest:
                data += rest
                received_at = time.monotonic()
        if len(data) == length:
            response = exchange.quick_decode(data)
            if response is not None:
                self._quiet_at = received_at + self._silence
                return response
        return self._receive_rest(exchange, data, needed, received_at, deadline)

    def _receive_rest(self, exchange: Exchange, data: bytes, needed: int, last_rx: float, deadline: float) -> Response:
        """Anything but a good normal answer: the receiver checks the bytes so far and each piece to come.

        ``data`` is what the reads so far gave (at least ``needed`` bytes unless the time ran out).
        """
        receiver = ResponseReceiver(exchange.request)
        while True:
            if needed:  # ``data`` is what a read of at least ``needed`` bytes gave
                if data:
                    receiver.feed(data)
                event = receiver.next_event()
                if event is NEED_DATA and len(data) < needed:
                    if receiver.received:
                        raise receiver.truncated_error()
                    raise TimeoutError(
                        f"{self.name}: no answer from unit {exchange.request.unit} within "
                        f"{exchange.policy.timeout:g} s to {exchange.frame.hex(' ').upper()}"
                    )
            else:
                event = receiver.next_event()
            if event is not NEED_DATA:
                self._quiet_at = last_rx + self._silence
                return event
            needed = receiver.bytes_needed()
            if needed:
                data = self.link.read(needed, deadline, receiver.expected_length - len(receiver.received))
                if data:
                    last_rx = time.monotonic()

    def _resync(self, policy: TransactionPolicy) -> None:
        """After a bad or missing answer: drop what is still coming until the line is quiet."""
        _, last = self.link.drain(max(self._silence, 3 * self.char_time), time.monotonic() + policy.timeout)
        self._quiet_at = (last if last is not None else time.monotonic()) + self._silence
