"""The Modbus RTU slave front end: simulated soft starters on a serial port, a new pty, or TCP.

Usage in a program (the CLI's ``starterbus simulate --modbus-rtu ...`` does the same)::

    sim = ModbusRtuSimulator({2: SimulatedStarter(profile)}, pty=True).start()
    url = sim.url(2)            # "modbus-rtu:///dev/pts/7?unit=2&baudrate=9600&parity=N&stopbits=1"
    ...
    sim.close()

One thread serves the line (or one per TCP connection). Requests are delimited by their predicted length, or
by a 3.5-character silence when the function code does not tell; frames with a bad CRC are dropped with
everything up to the next silence (a real slave does not answer them). Before answering, the slave waits
until the line has been silent for 3.5 characters since the last byte of the request.
"""

from __future__ import annotations

import functools
import os
import select
import socket
import termios
import threading
import time
import tty
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from starterbus.core import ConfigurationError, DecodeError, RunningSimulator, SimulatedStarter, precise_timers
from starterbus.transports.modbus.codec.messages import AnyRequest, ExceptionResponse, Response
from starterbus.transports.modbus.codec.receiver import NEED_DATA, RequestReceiver
from starterbus.transports.modbus.codec.timing import silent_interval
from starterbus.transports.modbus.driver.link import Link, SerialSettings
from starterbus.transports.modbus.settings import TRANSPORT
from starterbus.transports.modbus.slave import SlaveLogic

Trace = Callable[[str, bytes], None]  # ("rx" | "tx" | "drop", bytes)


@dataclass(frozen=True, slots=True)
class SlaveFault:
    """What the slave does with one request instead of answering it at once (:attr:`ModbusRtuSimulator.fault_hook`).

    ``exception``: answer this exception code and act on nothing (06 busy; 0x0B, a gateway's "target device
    failed to respond"); else act on the request (a write is written) and, if ``answer``, send the answer
    ``copies`` times back to back, ``delay`` seconds late (the serving thread waits: a slave serves one request
    at a time, so later requests wait too).
    """

    answer: bool = True
    delay: float = 0.0
    copies: int = 1
    exception: int | None = None


FaultHook = Callable[[AnyRequest], "SlaveFault | None"]


def fault_response(logic: SlaveLogic, request: AnyRequest, fault: SlaveFault | None) -> Response | None:
    """The answer to ``request`` under ``fault`` (None: none): the fault's exception, acting on nothing (for a
    served unit; none for a broadcast), else the slave's own, acted on. Whether and how it is sent is the fault's
    ``answer``, ``delay`` and ``copies``."""
    if fault is not None and fault.exception is not None:
        if request.unit not in logic.starters:
            return None
        return ExceptionResponse(request.unit, request.function, fault.exception)
    return logic.handle(request)


@dataclass(slots=True)
class SlaveCounters:
    requests: int = 0
    answers: int = 0
    ignored: int = 0  # other units, broadcasts
    overtaken: int = 0  # not answered: a later request was already waiting (see ModbusRtuSimulator._answer)
    errors: int = 0  # bad CRC, truncated, garbage
    last_errors: list[str] = field(default_factory=list)


class _Endpoint:
    """One byte stream the slave serves: read/write callables on a descriptor."""

    def __init__(self, fd: int, read: Callable[[int], bytes], write: Callable[[memoryview], int], name: str) -> None:
        self.fd = fd
        self.read = read
        self.write = write
        self.name = name


class ModbusRtuSimulator(RunningSimulator):
    """A Modbus RTU slave serving several simulated starters (one per unit id) on one line."""

    def __init__(
        self,
        starters: Mapping[int, SimulatedStarter],
        *,
        port: str | None = None,
        pty: bool = False,
        tcp: tuple[str, int] | None = None,
        baudrate: int = 9600,
        parity: str = "N",
        stopbits: int = 1,
        silence: float | None = None,
        trace: Trace | None = None,
        strict_line: bool = False,
    ) -> None:
        if sum((port is not None, pty, tcp is not None)) != 1:
            raise ConfigurationError("ModbusRtuSimulator needs exactly one of port=PATH, pty=True, tcp=(HOST, PORT)")
        self.logic = SlaveLogic(starters)
        self.port = port
        self.use_pty = pty
        self.tcp = tcp
        self.settings = SerialSettings(
            baudrate, parity.upper(), stopbits, 8, silent_interval(baudrate) if silence is None else silence
        )
        self.trace = trace
        #: on a pty, answer only a client whose line settings (speed, parity, stop bits) are the simulator's, as a
        #: real slave at another setting receives only garbage (how a bus scan is tested)
        self.strict_line = strict_line
        #: the client's parity when a test knows it: a pty keeps the speed and stop bits but no parity (Linux
        #: clears PARENB on a pty), so ``strict_line`` checks parity only through this
        self.client_parity: Callable[[], str | None] | None = None
        self._line_fd = -1
        #: called with each request that passed the CRC check, before it is acted on; what it returns changes
        #: how the slave answers (None: as usual). How tests make the device silent, slow, late, busy...
        self.fault_hook: FaultHook | None = None
        self.counters = SlaveCounters()
        self._stop_r, self._stop_w = -1, -1
        self._threads: list[threading.Thread] = []
        self._closers: list[Callable[[], None]] = []
        self._client_path = ""
        self._tcp_address: tuple[str, int] | None = None
        self._started = False
        self._closed = False
        self._lock = threading.Lock()

    @property
    def starters(self) -> dict[int, SimulatedStarter]:
        return self.logic.starters

    # -- lifecycle -------------------------------------------------------------------------------------------

    def start(self) -> ModbusRtuSimulator:
        if self._started:
            return self
        self._started = True
        self._stop_r, self._stop_w = os.pipe()
        try:
            if self.use_pty:
                self._start_pty()
            elif self.port is not None:
                self._start_port(self.port)
            else:
                assert self.tcp is not None
                self._start_tcp(*self.tcp)
        except BaseException:
            self.close()
            raise
        return self

    def _spawn(self, target: Callable[[], None], name: str) -> None:
        thread = threading.Thread(target=target, name=name, daemon=True)
        self._threads.append(thread)
        thread.start()

    def _start_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing: a client that opens the path later sees raw bytes
        self._closers += [lambda: os.close(master), lambda: os.close(slave)]
        self._line_fd = slave  # the client's tty: its settings are readable here
        self._client_path = os.ttyname(slave)
        os.set_blocking(master, False)
        endpoint = _Endpoint(master, lambda n: os.read(master, n), lambda d: os.write(master, d), self._client_path)
        self._spawn(lambda: self._serve(endpoint), f"modbus-rtu slave {self._client_path}")

    def _start_port(self, path: str) -> None:
        link = Link.open_serial(path, self.settings)
        self._closers.append(link.close)
        self._client_path = path
        endpoint = _Endpoint(link.fd, lambda n: os.read(link.fd, n), lambda d: os.write(link.fd, d), path)
        self._spawn(lambda: self._serve(endpoint), f"modbus-rtu slave {path}")

    def _start_tcp(self, host: str, port: int) -> None:
        server = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            server.bind((host, port))
        except OSError as exc:
            server.close()
            raise ConfigurationError(f"cannot listen on {host}:{port}: {exc}") from exc
        server.listen(8)
        server.setblocking(False)
        self._closers.append(server.close)
        bound = server.getsockname()
        self._tcp_address = (str(bound[0]), int(bound[1]))
        self._client_path = f"{self._tcp_address[0]}:{self._tcp_address[1]}"
        self._spawn(lambda: self._accept(server), f"modbus-rtu tcp {self._client_path}")

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
        if self._stop_w >= 0:
            os.write(self._stop_w, b"x")
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(timeout=2.0)
        for closer in reversed(self._closers):
            try:
                closer()
            except OSError:
                pass
        for fd in (self._stop_r, self._stop_w):
            if fd >= 0:
                os.close(fd)
        self._stop_r = self._stop_w = -1

    def __enter__(self) -> ModbusRtuSimulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- where clients connect --------------------------------------------------------------------------------

    @property
    def client_path(self) -> str:
        """The path a client opens (pty or serial port), or HOST:PORT for TCP."""
        if not self._started:
            raise ConfigurationError("the simulator is not started")
        return self._client_path

    @property
    def tcp_address(self) -> tuple[str, int]:
        if self._tcp_address is None:
            raise ConfigurationError("this simulator does not serve TCP")
        return self._tcp_address

    def url(self, unit: int, **params: object) -> str:
        """A device URL for one of the served units (extra URL parameters as keyword arguments)."""
        query: dict[str, object] = {"unit": unit}
        if self.tcp is None:
            s = self.settings
            query.update({"baudrate": s.baudrate, "parity": s.parity, "stopbits": s.stopbits})
        query.update(params)
        text = "&".join(f"{k}={v}" for k, v in query.items())
        if self.tcp is not None:
            return f"modbus-rtu+tcp://{self.client_path}?{text}"
        return f"modbus-rtu://{self.client_path}?{text}"

    def client_urls(self) -> dict[int, str]:
        """Unit id -> the URL a client in this process uses to reach that simulated starter."""
        return {unit: self.url(unit) for unit in sorted(self.starters)}

    def describe(self) -> list[str]:
        if self.tcp is not None:
            return [f"modbus-rtu-tcp: {self.client_path}"]
        return [f"modbus-rtu: {self.client_path}"]

    # -- serving ----------------------------------------------------------------------------------------------

    def _note(self, kind: str, data: bytes) -> None:
        if self.trace is not None:
            self.trace(kind, data)

    def _error(self, text: str) -> None:
        self.counters.errors += 1
        self.counters.last_errors = [*self.counters.last_errors[-9:], text]

    def _accept(self, server: socket.socket) -> None:
        while True:
            ready, _, _ = select.select([server.fileno(), self._stop_r], [], [])
            if self._stop_r in ready:
                return
            try:
                conn, peer = server.accept()
            except BlockingIOError:
                continue
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.setblocking(False)
            self._closers.append(conn.close)
            endpoint = _Endpoint(conn.fileno(), conn.recv, conn.send, f"{peer[0]}:{peer[1]}")
            self._spawn(functools.partial(self._serve, endpoint), f"modbus-rtu tcp client {endpoint.name}")

    def _serve(self, ep: _Endpoint) -> None:
        precise_timers()
        silence = self.settings.silence
        receiver = RequestReceiver()
        last_rx = 0.0
        discarding = False  # after a bad frame: drop bytes until the line is silent
        while True:
            busy = discarding or bool(receiver.pending)
            timeout = max(0.0, last_rx + silence - time.monotonic()) if busy else None
            ready, _, _ = select.select([ep.fd, self._stop_r], [], [], timeout)
            if self._stop_r in ready:
                return
            if ep.fd in ready:
                try:
                    data = ep.read(4096)
                except BlockingIOError:
                    continue
                except OSError:
                    return  # the pty/port went away
                if not data:
                    return  # TCP peer closed
                last_rx = time.monotonic()
                if discarding:
                    self._note("drop", data)
                    continue
                self._note("rx", data)
                receiver.feed(data)
            elif busy:  # the line went silent
                if discarding:
                    discarding = False
                    continue
                try:
                    request = receiver.end_of_frame()
                except DecodeError as exc:
                    self._error(str(exc))
                    continue
                if request is not None:
                    self._answer(ep, request, last_rx)
                continue
            waiting: AnyRequest | None = None  # requests found waiting together: only the last is answered
            while True:
                try:
                    event = receiver.next_event()
                except DecodeError as exc:
                    self._error(str(exc))
                    self._note("drop", receiver.reset())
                    discarding = True
                    break
                if event is NEED_DATA:
                    break
                if waiting is not None:
                    self._answer(ep, waiting, last_rx, overtaken=True)
                waiting = event
            if waiting is not None:
                self._answer(ep, waiting, last_rx)

    def client_settings_match(self) -> bool:
        """True unless ``strict_line`` and the client's tty is set to another speed or stop bits, or
        :attr:`client_parity` says another parity."""
        if not self.strict_line or self._line_fd < 0:
            return True
        attributes = termios.tcgetattr(self._line_fd)
        cflag, speed, settings = attributes[2], attributes[5], self.settings
        parity = self.client_parity() if self.client_parity is not None else None
        return (
            speed == getattr(termios, f"B{settings.baudrate}", None)
            and (2 if cflag & termios.CSTOPB else 1) == settings.stopbits
            and parity in (None, settings.parity)
        )

    def _answer(self, ep: _Endpoint, request: AnyRequest, last_rx: float, overtaken: bool = False) -> None:
        """Acts on ``request`` and answers it, unless ``overtaken``: a later request was already waiting behind
        it (this thread was held up, e.g. on a loaded machine), so the master has given up on it and its answer
        would only arrive in the later request's wait. It is acted on, but not answered."""
        if not self.client_settings_match():
            self._error(f"{ep.name}: the client's line settings are not {self.settings.describe()}: garbage")
            return
        self.counters.requests += 1
        hook = self.fault_hook
        fault = hook(request) if hook is not None else None
        response = fault_response(self.logic, request, fault)
        if response is None:
            self.counters.ignored += 1
            return
        if fault is not None and not fault.answer:
            return
        if overtaken:
            self.counters.overtaken += 1
            self._note("overtaken", response.encode())
            return
        frame = response.encode() * (fault.copies if fault is not None else 1)
        delay = last_rx + self.settings.silence - time.monotonic() + (fault.delay if fault is not None else 0.0)
        if delay > 0:
            time.sleep(delay)
        try:
            view = memoryview(frame)
            while view:
                try:
                    view = view[ep.write(view) :]
                except BlockingIOError:
                    select.select([], [ep.fd], [], 1.0)
        except OSError as exc:
            self._error(f"{ep.name}: write failed: {exc}")
            return
        self.counters.answers += 1
        self._note("tx", frame)


def parse_host_port(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit():
        raise ConfigurationError(f"{text!r} is not HOST:PORT (e.g. 127.0.0.1:5020)")
    return host.strip("[]") or "0.0.0.0", int(port)


__all__ = [
    "TRANSPORT",
    "FaultHook",
    "ModbusRtuSimulator",
    "SlaveCounters",
    "SlaveFault",
    "fault_response",
    "parse_host_port",
]
