"""The parts of bench/engine/edge_load.py that stand alone: the responder (a process of its own), what ``serve``
spends per sample, and a minimal asyncio scheduler for the drivers (the ``asyncio`` run)."""

from __future__ import annotations

import asyncio
import math
import selectors
import socket
import struct
import time

from starterbus.core.errors import StarterbusError, TransportError
from starterbus.core.media import TcpDriver
from starterbus.serve.metrics import MetricDef
from starterbus.serve.payloads import encode
from starterbus.serve.schema import DataType
from starterbus.transports.modbus.master.mbap import MbapEngine

__all__ = ["AsyncioDrivers", "Encoder", "serve"]


# -- the responder (a process of its own) ---------------------------------------------------------------------


def serve() -> None:
    """Answer every MBAP FC03 on every connection at once (registers: the transaction id and the unit)."""
    listener = socket.create_server(("127.0.0.1", 0))
    listener.setblocking(False)
    print(listener.getsockname()[1], flush=True)
    sel = selectors.DefaultSelector()
    sel.register(listener, selectors.EVENT_READ, None)
    buffers: dict[socket.socket, bytearray] = {}
    while True:
        for key, _ in sel.select():
            if key.data is None:
                conn, _addr = listener.accept()
                conn.setblocking(False)
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                sel.register(conn, selectors.EVENT_READ, True)
                buffers[conn] = bytearray()
                continue
            conn = key.fileobj  # type: ignore[assignment]
            try:
                data = conn.recv(65536)
            except OSError:  # a run ended with a transaction on the wire
                data = b""
            if not data:
                sel.unregister(conn)
                conn.close()
                continue
            buf = buffers[conn]
            buf += data
            out = bytearray()
            while len(buf) >= 12:
                tid, _pid, length, unit = struct.unpack(">HHHB", buf[:7])
                _fc, _addr, count = struct.unpack(">BHH", buf[7:12])
                del buf[: 6 + length]
                words = [(tid + i) & 0xFFFF for i in range(count - 1)] + [unit]
                out += struct.pack(f">HHHBBB{count}H", tid, 0, 3 + 2 * count, unit, 3, 2 * count, *words)
            conn.sendall(out)


# -- what serve spends per sample ---------------------------------------------------------------------------------


class Encoder:
    """What serve does per sample: a DDATA payload of ``metrics`` metrics."""

    def __init__(self, metrics: int) -> None:
        self.defs = [MetricDef(f"Inputs/m{i}", DataType.INT32, i + 1) for i in range(metrics)]
        self.seq = 0

    def __call__(self, sample: tuple[int, tuple[int, ...], float]) -> None:
        device, values, at = sample
        stamp = int(at * 1000)
        entries = [(d, values[i % len(values)] + device, stamp) for i, d in enumerate(self.defs)]
        encode(entries, timestamp=stamp, seq=self.seq, birth=False)
        self.seq = (self.seq + 1) % 256


# -- (b)'s loop: the scheduler's body on asyncio ------------------------------------------------------------------


class AsyncioDrivers:
    """The scheduler's loop body on an asyncio loop: a driver is stepped when its descriptor is ready
    (``add_reader``, or ``add_writer`` while connecting) or its deadline comes (``call_at``), and once soon after
    a submission; after each step its descriptor and deadline are looked at again."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        self._watched: dict[TcpDriver[MbapEngine], tuple[int, bool]] = {}
        self._timers: dict[TcpDriver[MbapEngine], asyncio.TimerHandle] = {}
        self._soon: set[TcpDriver[MbapEngine]] = set()

    def due(self, driver: TcpDriver[MbapEngine]) -> None:
        if driver not in self._soon:
            self._soon.add(driver)
            self.loop.call_soon(self._step_soon, driver)

    def _step_soon(self, driver: TcpDriver[MbapEngine]) -> None:
        self._soon.discard(driver)
        self.step(driver, False)

    def step(self, driver: TcpDriver[MbapEngine], ready: bool) -> None:
        try:
            driver.step(time.monotonic(), ready)
        except Exception as exc:
            error = exc if isinstance(exc, StarterbusError) else None
            driver.crash(error or TransportError(f"{driver.name}: {exc!r}"), time.monotonic())
        self.sync(driver)

    def sync(self, driver: TcpDriver[MbapEngine]) -> None:
        watched = (driver.fd, driver.writing)
        old = self._watched.get(driver)
        if old != watched:
            if old is not None and old[0] >= 0:
                (self.loop.remove_writer if old[1] else self.loop.remove_reader)(old[0])
            if watched[0] >= 0:
                (self.loop.add_writer if watched[1] else self.loop.add_reader)(watched[0], self.step, driver, True)
            self._watched[driver] = watched
        deadline = driver.deadline
        timer = self._timers.get(driver)
        if timer is not None and timer.when() == deadline:
            return
        if timer is not None:
            timer.cancel()
            del self._timers[driver]
        if deadline != math.inf:
            self._timers[driver] = self.loop.call_at(deadline, self._expire, driver)

    def _expire(self, driver: TcpDriver[MbapEngine]) -> None:
        self._timers.pop(driver, None)
        self.step(driver, False)
