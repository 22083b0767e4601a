"""One RTU line (a serial port, or a TCP connection to a serial device server) and its transactions.

A :class:`RtuLine` is shared by every device on it in one process (through a :class:`SharedPool`); its lock
makes one request + answer at a time, whatever thread asks. It keeps the 3.5-character silent interval by
remembering when the line was last busy, reads exactly the length the request predicts (the 5-byte header
first, which is a whole frame for an exception), and retries within the policy it is given.
"""

from __future__ import annotations

import os
import select
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from starterbus.core.errors import ConfigurationError, DecodeError, TimeoutError, TransportError
from starterbus.transports.modbus.frames import (
    BROADCAST,
    ReadRequest,
    Request,
    Response,
    expected_response_length,
)
from starterbus.transports.modbus.receiver import NEED_DATA, ResponseReceiver
from starterbus.transports.modbus.timing import char_time

_READ_CHUNK = 512


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
        write: Callable[[memoryview], int],
        close: Callable[[], None],
    ) -> None:
        self.fd = fd
        self.name = name
        self._read = read
        self._write = write
        self._close = close
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
        return cls(fd, path, lambda n: os.read(fd, n), lambda data: os.write(fd, data), port.close)

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
        view = memoryview(data)
        while view:
            try:
                sent = self._write(view)
            except BlockingIOError:
                select.select([], [self.fd], [], 1.0)
                continue
            except OSError as exc:
                raise self._fail("write", exc) from exc
            view = view[sent:]

    def read(self, size: int, deadline: float, limit: int = 0) -> bytes:
        """At least ``size`` bytes (fewer only when ``deadline``, monotonic, has passed), and no more than
        ``limit`` (default ``size``): what has already arrived beyond ``size`` is taken in the same call."""
        limit = max(size, limit)
        out = b""
        while len(out) < size:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            ready, _, _ = select.select([self.fd], [], [], remaining)
            if not ready:
                break
            chunk = self._recv(limit - len(out))
            if chunk is None:
                continue
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
            raise TransportError(f"{self.name}: the other end closed the connection")
        return chunk

    def wait_readable(self, timeout: float) -> bool:
        """True as soon as bytes are there to read; False after ``timeout`` seconds of nothing."""
        ready, _, _ = select.select([self.fd], [], [], max(0.0, timeout))
        return bool(ready)

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
            ready, _, _ = select.select([self.fd], [], [], wait)
            if not ready:
                return dropped, last
            chunk = self._recv(_READ_CHUNK)
            if chunk:
                dropped += chunk
                last = time.monotonic()

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._close()


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
        give_up = time.monotonic() + limit
        while self.link.wait_readable(self._quiet_at - time.monotonic()):
            dropped, last = self.link.drain(self.settings.silence, give_up)
            self._quiet_at = (last if last is not None else time.monotonic()) + self.settings.silence
            if time.monotonic() >= give_up:
                raise TransportError(
                    f"{self.name}: the line did not fall silent within {limit:g} s "
                    f"(last bytes {dropped[-16:].hex(' ').upper()})"
                )

    def transact(self, request: Request, policy: TransactionPolicy) -> Response | None:
        """Send ``request`` and return the checked answer (an ExceptionResponse is an answer, not an error).

        Broadcasts return None. Raises TimeoutError / DecodeError after the allowed attempts: reads are
        retried ``policy.retries`` times; a write only if ``policy.retry_writes`` (it may have been executed).
        """
        frame = request.encode()
        may_retry = isinstance(request, ReadRequest) or policy.retry_writes
        attempts = 1 + (policy.retries if may_retry else 0)
        with self.lock:
            self._usable_link()
            self.transactions += 1
            try:
                return self._attempts(request, frame, attempts, may_retry, policy)
            except TransportError as exc:
                if not isinstance(exc, TimeoutError):
                    self._broken = True  # the next transaction reopens / reconnects
                raise

    def _attempts(
        self, request: Request, frame: bytes, attempts: int, may_retry: bool, policy: TransactionPolicy
    ) -> Response | None:
        for attempt in range(1, attempts + 1):
            self._wait_quiet(max(1.0, policy.timeout))
            self.link.write(frame)
            wire_end = time.monotonic() + len(frame) * self.char_time
            if request.unit == BROADCAST:
                self._quiet_at = wire_end + max(policy.turnaround, self.settings.silence)
                return None
            try:
                return self._receive(request, frame, wire_end, policy)
            except (TimeoutError, DecodeError) as exc:
                self._resync(policy)
                if attempt == attempts:
                    note = f" (attempt {attempt} of {attempts}"
                    note += ")" if may_retry else "; a write is not repeated unless retry_writes=1)"
                    exc.args = (str(exc) + note,)
                    raise
                self.retries += 1
        raise AssertionError("unreachable")  # pragma: no cover

    def _receive(self, request: Request, frame: bytes, wire_end: float, policy: TransactionPolicy) -> Response:
        receiver = ResponseReceiver(request)
        deadline = wire_end + policy.timeout + expected_response_length(request) * self.char_time
        last_rx = wire_end
        while True:
            needed = receiver.bytes_needed()
            if needed:
                # at least the header (or the rest), at most the whole answer: one read when it is all there
                data = self.link.read(needed, deadline, receiver.expected_length - len(receiver.received))
                if data:
                    last_rx = time.monotonic()
                    receiver.feed(data)
                event = receiver.next_event()
                if event is NEED_DATA and len(data) < needed:
                    if receiver.received:
                        raise receiver.truncated_error()
                    raise TimeoutError(
                        f"{self.name}: no answer from unit {request.unit} within {policy.timeout:g} s "
                        f"to {frame.hex(' ').upper()}"
                    )
            else:
                event = receiver.next_event()
            if event is not NEED_DATA:
                self._quiet_at = last_rx + self.settings.silence
                return event

    def _resync(self, policy: TransactionPolicy) -> None:
        """After a bad or missing answer: drop what is still coming until the line is quiet."""
        _, last = self.link.drain(max(self.settings.silence, 3 * self.char_time), time.monotonic() + policy.timeout)
        self._quiet_at = (last if last is not None else time.monotonic()) + self.settings.silence
