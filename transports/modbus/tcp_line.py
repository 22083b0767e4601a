"""One Modbus TCP connection to a gateway (or a TCP device), shared by every unit behind it in this process.

The thin socket driver around :class:`~starterbus.transports.modbus.mbap.MbapEngine`: requests are written
under a lock, one reader thread takes the answers and hands each to the transaction waiting for its id. At most
``outstanding`` transactions wait at once (the others queue for a slot). A transaction that times out stops
waiting: its late answer is then stale and dropped. A 0x0A / 0x0B exception is the gateway saying the device
behind it is unreachable: a failed attempt like a timeout (retried within the policy), never a refusal. A broken
connection fails every waiting transaction; the next request reconnects, after a backoff if connecting failed.
"""

from __future__ import annotations

import select
import socket
import threading
import time
from collections.abc import Callable, Sequence

from starterbus.core.errors import DecodeError, StarterbusError, TimeoutError, TransportError
from starterbus.core.transport import TransportCounters
from starterbus.spaces.modbus import GATEWAY_EXCEPTIONS, STANDARD_EXCEPTION_TEXTS
from starterbus.transports.modbus.exchange import Exchange
from starterbus.transports.modbus.frames import ExceptionResponse, Response, decode_response
from starterbus.transports.modbus.mbap import HEADER_LENGTH, Adu, MbapEngine

Clock = Callable[[], float]
BACKOFF_FIRST = 0.1  # s: the wait after a first failed reconnection, doubled after each failure
BACKOFF_MAX = 5.0


class _Waiter:
    __slots__ = ("adu", "error", "event", "transaction")

    def __init__(self, transaction: int) -> None:
        self.transaction = transaction
        self.event = threading.Event()
        self.adu: Adu | None = None
        self.error: StarterbusError | None = None


class MbapConnection:
    """A Modbus TCP client connection; thread-safe. ``run`` has the signature of ``RtuLine.run``."""

    def __init__(
        self,
        host: str,
        port: int,
        outstanding: int,
        connect_timeout: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.host, self.port = host, port
        self.name = f"{host}:{port}"
        self.outstanding = outstanding
        self._connect_timeout = connect_timeout
        self._clock = clock
        self._lock = threading.Lock()  # the state below; the send
        self._slots = threading.BoundedSemaphore(outstanding)
        self._engine = MbapEngine()
        self._waiters: dict[int, _Waiter] = {}
        self._sock: socket.socket | None = None
        self._reader: threading.Thread | None = None
        self._wake: tuple[socket.socket, socket.socket] | None = None
        self._closed = False
        self._backoff = 0.0
        self._retry_at = 0.0
        self._last_error = ""
        self.connects = 0
        with self._lock:
            self._connect()

    # -- connection ---------------------------------------------------------------------------------------------

    def _connect(self) -> None:
        """Connect (the lock held); TransportError naming the gateway on failure, and the next try backs off."""
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self._connect_timeout)
        except OSError as exc:
            self._backoff = min(max(2 * self._backoff, BACKOFF_FIRST), BACKOFF_MAX)
            self._retry_at = self._clock() + self._backoff
            self._last_error = f"cannot connect to {self.name}: {exc}"
            raise TransportError(self._last_error) from exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(None)
        self._backoff = 0.0
        self._engine.reset()
        self._sock = sock
        wake_r, wake_w = socket.socketpair()  # closing wake_w ends the reader
        self._wake = (wake_r, wake_w)
        self.connects += 1
        reader = threading.Thread(target=self._read_loop, args=(sock, wake_r), name=f"modbus-tcp {self.name}")
        reader.daemon = True
        self._reader = reader
        reader.start()

    def _usable(self) -> socket.socket:
        """The socket, reconnected if it broke (the lock held)."""
        if self._closed:
            raise TransportError(f"{self.name} is closed")
        if self._sock is None:
            wait = self._retry_at - self._clock()
            if wait > 0:
                raise TransportError(f"{self.name}: reconnecting in {wait:.1f} s ({self._last_error})")
            self._connect()
        assert self._sock is not None
        return self._sock

    def _broken(self, sock: socket.socket, why: str) -> None:
        """The connection ``sock`` is unusable: fail every waiting transaction; the next request reconnects."""
        with self._lock:
            if self._sock is not sock:
                return
            self._sock = None
            self._last_error = why
            waiters, self._waiters = self._waiters, {}
            self._engine.reset()
            wake, self._wake = self._wake, None
        for waiter in waiters.values():
            waiter.error = TransportError(f"{self.name}: {why}")
            waiter.event.set()
        try:
            sock.shutdown(socket.SHUT_RDWR)  # the reader closes it: closing it under its select would be a race
        except OSError:
            pass
        if wake is not None:
            wake[1].close()  # the reader wakes and ends

    def _read_loop(self, sock: socket.socket, wake: socket.socket) -> None:
        try:
            while True:
                ready, _, _ = select.select([sock, wake], [], [])
                if wake in ready:
                    return
                try:
                    data = sock.recv(4096)
                except OSError as exc:
                    self._broken(sock, f"read failed: {exc}")
                    return
                if not data:
                    self._broken(sock, "the gateway closed the connection")
                    return
                error: DecodeError | None = None
                with self._lock:
                    if self._sock is not sock:
                        return
                    try:
                        adus = self._engine.feed(data)
                    except DecodeError as exc:
                        adus, error = [], exc
                    found = [(self._waiters.pop(a.transaction, None), a) for a in adus]
                for waiter, adu in found:
                    if waiter is not None:
                        waiter.adu = adu
                        waiter.event.set()
                if error is not None:
                    self._broken(sock, str(error))
                    return
        finally:
            wake.close()
            sock.close()

    def close(self) -> None:
        with self._lock:
            self._closed = True
            sock, reader = self._sock, self._reader
        if sock is not None:
            self._broken(sock, "closed")
        if reader is not None and reader is not threading.current_thread():
            reader.join(timeout=5.0)

    @property
    def stale(self) -> int:
        """Answers dropped because no transaction waited for their id."""
        return self._engine.stale

    # -- transactions ---------------------------------------------------------------------------------------------

    def send(self, exchange: Exchange, wait_slot: float) -> _Waiter:
        """Take a slot (at most ``wait_slot`` s), number the request and write it; the slot is the caller's until
        :meth:`receive` (or a raise here, which gives it back)."""
        if not self._slots.acquire(timeout=wait_slot):
            raise TimeoutError(f"{self.name}: {self.outstanding} request(s) outstanding for {wait_slot:g} s")
        try:
            with self._lock:
                sock = self._usable()
                transaction, adu = self._engine.request(exchange.request.unit, exchange.frame[1:-2])
                waiter = _Waiter(transaction)
                self._waiters[transaction] = waiter
                try:
                    sock.sendall(adu)
                except OSError as exc:
                    error = exc
                else:
                    return waiter
        except BaseException:
            self._slots.release()
            raise
        self._slots.release()
        self._broken(sock, f"write failed: {error}")
        raise TransportError(f"{self.name}: write failed: {error}")

    def receive(self, exchange: Exchange, waiter: _Waiter) -> Response:
        """The answer to the transaction ``waiter`` stands for, within the policy's timeout; gives the slot back.

        TimeoutError: no answer (its id is then forgotten: a late answer is stale), or the gateway's 0x0A / 0x0B;
        DecodeError: an answer with the id that does not answer the request (unit, function, length, echo)."""
        try:
            if not waiter.event.wait(exchange.policy.timeout):
                with self._lock:
                    self._waiters.pop(waiter.transaction, None)
                    self._engine.forget(waiter.transaction)
                if waiter.adu is None and waiter.error is None:
                    raise TimeoutError(
                        f"{self.name}: no answer from unit {exchange.request.unit} within "
                        f"{exchange.policy.timeout:g} s (transaction {waiter.transaction})"
                    )
            if waiter.error is not None:
                raise waiter.error
            adu = waiter.adu
            assert adu is not None
        finally:
            self._slots.release()
        if adu.unit != exchange.request.unit:
            raise DecodeError(
                f"answer from unit {adu.unit} to transaction {adu.transaction}, which went to unit "
                f"{exchange.request.unit}",
                adu.pdu,
                "unit",
            )
        response = decode_response(bytes((adu.unit,)) + adu.pdu, crc=False, request=exchange.request)
        if isinstance(response, ExceptionResponse) and response.code in GATEWAY_EXCEPTIONS:
            raise TimeoutError(
                f"{self.name}: the device behind the gateway is unreachable: unit {adu.unit}, exception "
                f"0x{response.code:02X} ({STANDARD_EXCEPTION_TEXTS[response.code]})"
            )
        return response

    def run(self, exchange: Exchange, counters: TransportCounters | None = None) -> Response | None:
        """One transaction with the policy's attempts (reads retried, writes only with ``retry_writes``)."""
        return self.run_many([exchange], counters)[0]

    def run_many(self, exchanges: Sequence[Exchange], counters: TransportCounters | None = None) -> list[Response]:
        """The transactions, up to ``outstanding`` on the wire at once; answers in the order of ``exchanges``.
        A failed first attempt is repeated on its own, within its policy; the first failure for good raises."""
        started: list[tuple[Exchange, _Waiter | StarterbusError]] = []
        out: list[Response] = []
        index = 0
        while index < len(exchanges) or started:
            while index < len(exchanges) and len(started) < self.outstanding:
                exchange = exchanges[index]
                index += 1
                try:
                    started.append((exchange, self.send(exchange, self._slot_wait(exchange))))
                except StarterbusError as exc:
                    started.append((exchange, exc))
            exchange, waiting = started.pop(0)
            out.append(self._finish(exchange, waiting, counters))
        return out

    def _slot_wait(self, exchange: Exchange) -> float:
        return max(1.0, exchange.policy.timeout * self.outstanding * exchange.attempts)

    def _finish(
        self, exchange: Exchange, first: _Waiter | StarterbusError, counters: TransportCounters | None
    ) -> Response:
        attempt = 1
        began = self._clock()
        while True:
            try:
                if isinstance(first, StarterbusError):
                    raise first
                response = self.receive(exchange, first)
            except (TimeoutError, DecodeError) as exc:
                if attempt >= exchange.attempts:
                    self._count(counters, exchange, attempt, 0, exc, began)
                    note = f" (attempt {attempt} of {exchange.attempts}"
                    note += ")" if exchange.may_retry else "; a write is not repeated unless retry_writes=1)"
                    exc.args = (str(exc) + note,)
                    raise
            except StarterbusError as exc:
                self._count(counters, exchange, attempt, 0, exc, began)
                raise
            else:
                self._count(counters, exchange, attempt, HEADER_LENGTH + len(_pdu(response)), None, began)
                return response
            attempt += 1
            try:
                first = self.send(exchange, self._slot_wait(exchange))
            except StarterbusError as exc:
                first = exc

    def _count(
        self,
        counters: TransportCounters | None,
        exchange: Exchange,
        sent: int,
        received: int,
        failure: StarterbusError | None,
        began: float,
    ) -> None:
        if counters is None:
            return
        request_bytes = HEADER_LENGTH + len(exchange.frame) - 3  # MBAP header + PDU (no unit byte, no CRC)
        counters.transactions += 1
        counters.requests += sent
        counters.retries += sent - 1
        counters.timeouts += isinstance(failure, TimeoutError)
        counters.errors += failure is not None
        counters.bytes_sent += sent * request_bytes
        counters.bytes_received += received
        counters.busy_time += self._clock() - began
        # the time the requests and the answer take on the serial line behind the gateway (RTU framing)
        char = exchange.wire / len(exchange.frame)
        counters.wire_time += sent * exchange.wire + (exchange.answer_length * char if received else 0.0)


def _pdu(response: Response) -> bytes:
    return response.encode()[1:-2]
