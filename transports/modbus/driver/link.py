"""Bytes in and out of one RTU line: the POSIX fast path, and pyserial for everything else.

:class:`Link` is the fast path: ``select`` + ``os.read``/``os.write`` on a file descriptor (a serial port or
pty opened and configured by pyserial, or a TCP socket to a serial device server). :class:`PySerialLink` does
the same through pyserial's own ``read``/``write``: Windows COM ports, pyserial's URL handlers
(``rfc2217://``, ``socket://``) and any port when the URL says ``io=pyserial``. Both read at most what they
are asked for, so bytes after an answer stay in the input for the silence check.
"""

from __future__ import annotations

import functools
import os
import re
import select
import socket
import stat
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from starterbus.core import TransportError, address_of, connect_failure, start_connect

if TYPE_CHECKING:
    import serial

_READ_CHUNK = 512
_NOTHING: tuple[int, ...] = ()  # the empty write and error sets of select.select
_COM_PORT = re.compile(r"/?(COM[1-9][0-9]*)", re.IGNORECASE)
_LINUX = sys.platform.startswith("linux")  # a variable: mypy checks both branches on every platform


@dataclass(frozen=True, slots=True)
class SerialSettings:
    """How the UART frames characters; ``silence`` is the interval kept between frames, in seconds.

    ``wire_check``: apply the wire-time rule (an answer cannot be faster than the wire); None: only on a real
    serial port (not a pty, not TCP).
    """

    baudrate: int = 9600
    parity: str = "N"
    stopbits: int = 1
    bytesize: int = 8
    silence: float = 0.0
    wire_check: bool | None = None

    def describe(self) -> str:
        return f"{self.baudrate} {self.bytesize}{self.parity}{self.stopbits}"

    @property
    def min_char_time(self) -> float:
        """The shortest time one character takes on the wire: start bit, data bits, parity bit, stop bits."""
        return (1 + self.bytesize + (self.parity != "N") + self.stopbits) / self.baudrate


def com_port(text: str) -> str | None:
    """``COM3`` for ``COM3``, ``/COM3`` or ``com3`` (a Windows COM port name), else None."""
    match = _COM_PORT.fullmatch(text)
    return match.group(1).upper() if match else None


def device_name(port: str, platform: str = sys.platform) -> str:
    """The name to open ``port`` by: on Windows a COM port in the ``\\\\.\\COM10`` form, which every COM port
    accepts and COM10 and above need."""
    if platform == "win32" and com_port(port):
        return "\\\\.\\" + port.upper()
    return port


def is_pseudo_terminal(fd: int) -> bool:
    """True for the slave side of a pty (no baud rate, no wire timing)."""
    try:
        info = os.fstat(fd)
    except OSError:
        return False
    if not stat.S_ISCHR(info.st_mode):
        return False
    if _LINUX:
        return 136 <= os.major(info.st_rdev) <= 143  # Unix98 pty slaves
    try:
        name = os.ttyname(fd)
    except OSError:
        return False
    return name.startswith(("/dev/pts/", "/dev/ttys", "/dev/ttyp"))


def is_real_serial(fd: int) -> bool:
    return os.isatty(fd) and not is_pseudo_terminal(fd)


class Link:
    """Bytes in and out of one file descriptor (serial port, pty, socket) with deadlines, never polling."""

    def __init__(
        self,
        fd: int,
        name: str,
        read: Callable[[int], bytes],
        write: Callable[[bytes | memoryview], int],
        close: Callable[[], None],
        *,
        real_serial: bool = False,
    ) -> None:
        self.fd = fd
        self.name = name
        self.real_serial = real_serial  # a UART at a baud rate: answers take their wire time
        self._read = read
        self._write = write
        self._close = close
        self._fds = [fd]  # select's read set, built once
        self.closed = False
        try:
            self._nonblocking = not os.get_blocking(fd)  # then a read with nothing there returns at once
        except OSError:
            self._nonblocking = False

    @classmethod
    def open_serial(cls, path: str, settings: SerialSettings) -> Link:
        port = open_pyserial(path, settings)
        try:
            fd = port.fileno()
        except Exception as exc:
            port.close()
            raise TransportError(f"{path}: the serial port gives no file descriptor (use io=pyserial): {exc}") from exc
        return cls(
            fd, path, functools.partial(os.read, fd), functools.partial(os.write, fd), port.close,
            real_serial=is_real_serial(fd),
        )  # fmt: skip

    @classmethod
    def connect_tcp(cls, host: str, port: int, timeout: float) -> Link:
        try:  # the name looked up here and kept: the loop's reconnects (TcpConnect) take that address, never a DNS wait
            sock = socket.create_connection(address_of(host, port)[3][:2], timeout=timeout)
        except OSError as exc:
            raise TransportError(f"cannot connect to {host}:{port}: {exc}") from exc
        return cls.on_socket(sock, host, port)

    @classmethod
    def on_socket(cls, sock: socket.socket, host: str, port: int) -> Link:
        """The link on a connected TCP socket."""
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(False)
        return cls(sock.fileno(), f"{host}:{port}", sock.recv, sock.send, sock.close)

    def _fail(self, what: str, exc: BaseException) -> TransportError:
        return TransportError(f"{self.name}: {what} failed: {exc}")

    def write(self, data: bytes) -> None:
        self.transfer(data, 0, 0.0, 0, 0.0)

    def transfer(self, frame: bytes, size: int, deadline: float, limit: int, wait: float) -> bytes:
        """:meth:`write` ``frame``, then :meth:`read` ``size`` to ``limit`` bytes (``wait``: seconds from now to
        ``deadline``): every transaction's I/O in one call; the whole answer usually comes with one ``select``."""
        try:
            sent = self._write(frame)
        except BlockingIOError:
            sent = 0
        except OSError as exc:
            raise self._fail("write", exc) from exc
        if sent < len(frame):
            self._write_rest(memoryview(frame)[sent:])
        if not size:
            return b""
        if not select.select(self._fds, _NOTHING, _NOTHING, wait)[0]:
            return b""
        try:
            out = self._read(limit)
        except BlockingIOError:
            out = b""
        except OSError as exc:
            raise self._fail("read", exc) from exc
        else:
            if not out:
                raise self._hung_up()
        if len(out) >= size:
            return out
        return out + self.read(size - len(out), deadline, limit - len(out))

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
            out += self._recv(limit - len(out))
        return out

    def _recv(self, size: int, *, ended: bool = True) -> bytes:
        """What one read gives (b"" if it would block); reading nothing means the other end closed, unless
        ``ended`` is False (a tty in raw mode also reads nothing when there is nothing)."""
        try:
            chunk = self._read(size)
        except BlockingIOError:
            return b""
        except OSError as exc:
            raise self._fail("read", exc) from exc
        if not chunk and ended:
            raise self._hung_up()
        return chunk

    def _hung_up(self) -> TransportError:
        return TransportError(f"{self.name}: the other end closed the connection")

    def wait_readable(self, timeout: float) -> bool:
        """True as soon as bytes are there to read; False after ``timeout`` seconds of nothing."""
        return select.select(self._fds, _NOTHING, _NOTHING, timeout if timeout > 0.0 else 0.0)[0] != []

    def take_input(self, limit: int = _READ_CHUNK) -> bytes:
        """Whatever input is waiting, up to ``limit`` bytes, without waiting (b"" if none): how input is
        discarded, and how a poller that waits on many lines at once reads."""
        if not select.select(self._fds, _NOTHING, _NOTHING, 0)[0]:
            return b""
        return self._recv(limit)

    def read_ready(self, limit: int) -> bytes:
        """:meth:`take_input` when bytes are probably there (a poller was told so): read first, one system
        call instead of two."""
        if self._nonblocking:
            chunk = self._recv(limit, ended=False)
            if chunk:
                return chunk
        return self.take_input(limit)  # nothing, or the end: select tells which

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._close()


#: pyserial lets termios.error (no OSError) out of its last tcsetattr: a pty refusing a parity change, say
_TERMIOS_ERRORS: tuple[type[Exception], ...] = ()
if sys.platform != "win32":
    import termios

    _TERMIOS_ERRORS = (termios.error,)


class TcpConnect:
    """A TCP connection to a serial device server being made without blocking (the I/O loop's reconnect, as
    :class:`~starterbus.core.media.TcpDriver` connects): :meth:`link` looks whether it is made. Errors as
    :meth:`Link.connect_tcp`'s."""

    def __init__(self, host: str, port: int, timeout: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.host, self.port = host, port
        self._clock = clock
        self._give_up = clock() + timeout
        try:
            self._sock, self._made = start_connect(host, port)
        except OSError as exc:
            raise self._error(str(exc)) from exc

    def _error(self, why: str) -> TransportError:
        return TransportError(f"cannot connect to {self.host}:{self.port}: {why}")

    def link(self) -> Link | None:
        """The link once connected; None while the connection is being made; a TransportError if it failed or
        the timeout passed (the socket closed)."""
        sock = self._sock
        if not self._made:
            if not select.select(_NOTHING, [sock], _NOTHING, 0)[1]:
                if self._clock() < self._give_up:
                    return None
                self.close()
                raise self._error("timed out")
            failure = connect_failure(sock)
            if failure is not None:
                self.close()
                raise self._error(str(failure))
        return Link.on_socket(sock, self.host, self.port)

    def close(self) -> None:
        self._sock.close()


def open_pyserial(target: str, settings: SerialSettings, *, url: bool = False) -> serial.SerialBase:
    """A pyserial port: a device path / COM port (opened exclusively), or with ``url`` a pyserial URL."""
    import serial

    options = {
        "baudrate": settings.baudrate, "bytesize": settings.bytesize, "parity": settings.parity,
        "stopbits": settings.stopbits, "timeout": 0,
    }  # fmt: skip
    try:
        if url:
            port: serial.SerialBase = serial.serial_for_url(target, **options)
        else:
            port = serial.Serial(port=device_name(target), exclusive=True, **options)
    except (serial.SerialException, ValueError, OSError, ImportError, *_TERMIOS_ERRORS) as exc:
        hint = " (COM ports exist on Windows)" if com_port(target) and sys.platform != "win32" else ""
        raise TransportError(f"cannot open serial port {target} ({settings.describe()}){hint}: {exc}") from exc
    return port


#: pyserial classes whose read() takes ``_timeout`` at each call; setting the ``timeout`` property instead
#: would reconfigure the port (for rfc2217: renegotiate every setting over the network) before each read
_TIMEOUT_READ_PER_CALL = ("serial.serialposix", "serial.rfc2217", "serial.urlhandler.protocol_socket")


class PySerialLink(Link):
    """The :class:`Link` operations through pyserial's read/write (no file descriptor needed)."""

    def __init__(self, port: serial.SerialBase, name: str, *, real_serial: bool = False) -> None:
        self.fd = -1
        self.name = name
        self.real_serial = real_serial
        self.closed = False
        self._port = port
        self._pending = b""  # bytes wait_readable took to find out that there were some
        self._direct = any(cls.__module__ in _TIMEOUT_READ_PER_CALL for cls in type(port).__mro__)

    @classmethod
    def open(cls, target: str, settings: SerialSettings, *, url: bool = False) -> PySerialLink:
        port = open_pyserial(target, settings, url=url)
        real = False
        if not url:
            try:
                real = is_real_serial(port.fileno())
            except Exception:  # no descriptor (Windows): a COM port is a UART
                real = True
        return cls(port, target, real_serial=real)

    def _timeout(self, seconds: float) -> None:
        seconds = max(0.0, seconds)
        if self._direct:
            self._port._timeout = seconds
        elif self._port.timeout != seconds:
            self._port.timeout = seconds

    def _port_read(self, size: int, timeout: float) -> bytes:
        import serial

        self._timeout(timeout)
        try:
            return bytes(self._port.read(size))
        except (serial.SerialException, OSError) as exc:
            raise self._fail("read", exc) from exc

    def write(self, data: bytes) -> None:
        import serial

        try:
            self._port.write(data)
        except (serial.SerialException, OSError) as exc:
            raise self._fail("write", exc) from exc

    def transfer(self, frame: bytes, size: int, deadline: float, limit: int, wait: float) -> bytes:
        self.write(frame)
        return self.read(size, deadline, limit, wait)

    def read(self, size: int, deadline: float, limit: int = 0, wait: float | None = None) -> bytes:
        """At least ``size`` bytes (fewer only when ``deadline`` has passed), never more than ``size``."""
        out, self._pending = self._pending[:size], self._pending[size:]
        if len(out) < size:
            out += self._port_read(size - len(out), deadline - time.monotonic() if wait is None else wait)
        return out

    def wait_readable(self, timeout: float) -> bool:
        if not self._pending:
            self._pending = self._port_read(1, timeout)
        return bool(self._pending)

    def read_ready(self, limit: int) -> bytes:
        return self.take_input(limit)

    def take_input(self, limit: int = _READ_CHUNK) -> bytes:
        out, self._pending = self._pending[:limit], self._pending[limit:]
        return out + self._port_read(limit - len(out), 0.0) if len(out) < limit else out

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._port.close()
