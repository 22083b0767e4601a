"""A TCP client connection as a medium: connected without blocking the loop, made again after a loss.

A host name is never looked up in the loop (``resolve.py``): the connection takes the address its opener looked up
in its own thread, and after a failed connect the name is looked up again in a thread of its own.

The connection is made when the engine has work and none is up. A connection lost (the peer closed it, a read
or write failed, the engine found the stream out of step) fails the tickets that were sent; the queued ones
go out on the next connection, made at once. A connection attempt that fails (refused, unreachable, not made
within ``connect_timeout``) backs off: :data:`BACKOFF_FIRST`, doubled up to :data:`BACKOFF_MAX`; meanwhile every
ticket fails at once, without touching the network.
"""

from __future__ import annotations

import errno
import os
import select
import socket
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, TypeVar

from starterbus.core.engine import StreamEngine
from starterbus.core.errors import StarterbusError, TransportError
from starterbus.core.media.driver import StreamDriver
from starterbus.core.media.resolve import kept_address, look_up_later

__all__ = [
    "BACKOFF_FIRST",
    "BACKOFF_MAX",
    "CONNECT_AT_LEAST",
    "TcpDriver",
    "connect_failure",
    "connect_timeout",
    "start_connect",
]

BACKOFF_FIRST = 0.1  # s: the wait after a first failed connection attempt, doubled after each failure
BACKOFF_MAX = 5.0
CONNECT_AT_LEAST = 1.0  # s: a connection is given this long at least, whatever a device's answers are given


def connect_timeout(timeout: float) -> float:
    """How long a connection to a device (or a server in front of devices) may take, for a device's ``timeout``."""
    return max(timeout, CONNECT_AT_LEAST)


E = TypeVar("E", bound=StreamEngine[Any, Any])


def start_connect(host: str, port: int) -> tuple[socket.socket, bool]:
    """A TCP connection to ``host:port`` begun without waiting: its non-blocking socket, and whether it is made
    already (else: once the socket is writable, :func:`connect_failure` says how it ended). An :class:`OSError` if
    it cannot begin (no address known for the name yet: ``resolve.kept_address``, which never waits on a name
    server; refused at once); the socket is closed then."""
    family, kind, proto, address = kept_address(host, port)
    sock = socket.socket(family, kind, proto)
    sock.setblocking(False)
    code = sock.connect_ex(address)
    if code == 0:
        return sock, True
    if code in (errno.EINPROGRESS, errno.EWOULDBLOCK, errno.EAGAIN):
        return sock, False
    sock.close()
    raise OSError(code, os.strerror(code))


def connect_failure(sock: socket.socket) -> OSError | None:
    """Why a connection begun by :func:`start_connect` failed, once its socket is writable (None: it is made)."""
    code = sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
    return OSError(code, os.strerror(code)) if code else None


class TcpDriver(StreamDriver[E]):
    """A stream engine on a TCP client connection to ``host:port``."""

    def __init__(self, host: str, port: int, make_engine: Callable[[], E], connect_timeout: float) -> None:
        super().__init__(f"{host}:{port}", make_engine)
        self.host, self.port = host, port
        self.connect_timeout = connect_timeout
        self.connects = 0
        self.closed = False
        self.last_error = ""
        self._connecting: socket.socket | None = None
        self._connect_by = 0.0
        self._backoff = 0.0
        self._retry_at = 0.0
        self._opened: list[Future[None]] = []

    @property
    def fd(self) -> int:
        if self._connecting is not None:
            return self._connecting.fileno()
        return super().fd

    @property
    def writing(self) -> bool:
        return self._connecting is not None

    @property
    def deadline(self) -> float:
        if self._connecting is not None:
            return self._connect_by
        return float(self.engine.deadline)

    @property
    def connected(self) -> bool:
        return self.stream is not None

    def open(self, now: float) -> Future[None]:
        """Connect now (if not connected or connecting); the future ends with the attempt."""
        future: Future[None] = Future()
        if self.stream is not None:
            future.set_result(None)
            return future
        self._opened.append(future)
        if self._connecting is None:
            self._connect(now)
        return future

    def close(self, now: float) -> None:
        """For good: the connection closed, every ticket fails."""
        self.closed = True
        if self._connecting is not None:
            self._connect_failed(OSError("closed while connecting"), now)
        self.close_stream()
        error = TransportError(f"{self.name} is closed")
        self.engine.lost(error, now)
        self.engine.refuse(error, now)
        self.complete(now)

    def check(self, now: float) -> bool:
        """Whether the connection is up, after taking what is waiting on it (a close by the peer is seen)."""
        self.step(now, False)
        return self.stream is not None

    # -- the loop body's hooks ---------------------------------------------------------------------------------

    def step(self, now: float, ready: bool) -> None:
        stream = self.stream
        if not ready and stream is not None and select.select((stream,), (), (), 0)[0]:
            ready = True  # read before writing: a connection the peer closed while idle is made again first
        super().step(now, ready)

    def usable(self, now: float) -> bool:
        if self.stream is not None:
            return True
        if self._connecting is not None:
            if now >= self._connect_by:
                self._connect_failed(OSError(f"no connection within {self.connect_timeout:g} s"), now)
            return False
        if not self.engine.pending:
            return False
        if self.closed:
            self.engine.refuse(TransportError(f"{self.name} is closed"), now)
        elif now < self._retry_at:
            wait = self._retry_at - now
            self.engine.refuse(TransportError(f"{self.name}: reconnecting in {wait:.1f} s ({self.last_error})"), now)
        else:
            self._connect(now)
        return False

    def take_input(self, now: float) -> None:
        sock = self._connecting
        if sock is None:
            super().take_input(now)
            broken = self.engine.broken
            if broken is not None and self.stream is not None:
                self.lost(broken, now)
            return
        failure = connect_failure(sock)
        if failure is not None:
            self._connect_failed(failure, now)
            return
        self._connected(sock)

    def lost(self, why: str, now: float) -> None:
        self.close_stream()
        self.last_error = why
        self.engine.lost(TransportError(f"{self.name}: {why}"), now)

    def refuse(self, error: StarterbusError, now: float) -> None:
        self.engine.refuse(error, now)

    def drop_medium(self) -> None:
        sock, self._connecting = self._connecting, None
        if sock is not None:
            sock.close()
        self.close_stream()

    # -- connecting -------------------------------------------------------------------------------------------

    def _connect(self, now: float) -> None:
        try:
            sock, made = start_connect(self.host, self.port)
        except OSError as exc:
            self._connect_failed(exc, now)
            return
        if made:
            self._connected(sock)
        else:
            self._connecting = sock
            self._connect_by = now + self.connect_timeout

    def _connected(self, sock: socket.socket) -> None:
        self._connecting = None
        sock.setblocking(True)  # writes of a few requests never wait; reads only after select said ready
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.stream = sock
        self._backoff = 0.0
        self.connects += 1
        opened, self._opened = self._opened, []
        for future in opened:
            future.set_result(None)

    def _connect_failed(self, exc: OSError, now: float) -> None:
        sock, self._connecting = self._connecting, None
        if sock is not None:
            sock.close()
        self._backoff = min(max(2 * self._backoff, BACKOFF_FIRST), BACKOFF_MAX)
        self._retry_at = now + self._backoff
        self.last_error = f"cannot connect to {self.name}: {exc}"
        look_up_later(self.host, self.port)  # (a name's address may have changed; a numeric one is not looked up)
        error = TransportError(self.last_error)
        self.engine.refuse(error, now)
        opened, self._opened = self._opened, []
        for future in opened:
            future.set_exception(error)
