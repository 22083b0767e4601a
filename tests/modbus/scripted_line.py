"""A fake clock and a link whose input arrives at scripted times, to drive an RTU line deterministically:
the blocking :class:`RtuLine` (waiting advances the clock to the next event) and a non-blocking
:class:`~starterbus.core.polling.PollTask` (:func:`drive` advances it the way a poller would)."""

from __future__ import annotations

import itertools
from collections.abc import Callable

from starterbus.core.errors import StarterbusError
from starterbus.core.polling import PollResult
from starterbus.transports.modbus.codec.frames import ExceptionResponse, ReadResponse
from starterbus.transports.modbus.driver.line import RtuLine
from starterbus.transports.modbus.driver.line_task import LineTask
from starterbus.transports.modbus.driver.link import Link, SerialSettings

SILENCE = 0.002
BAUD = 19200


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


Responder = Callable[[int, bytes, float], list[tuple[float, bytes]]]  # (request #, frame, sent at) -> arrivals


class ScriptedLink(Link):
    """A link whose input arrives at scripted times; waiting advances the fake clock to the next event.

    Its :attr:`fd` is a number no file has: :func:`drive` reads it as "wake me when input is here"."""

    _numbers = itertools.count(10_000)

    def __init__(self, clock: FakeClock, responder: Responder) -> None:
        self.fd = next(self._numbers)
        self.name = "scripted"
        self.real_serial = False
        self.closed = False
        self.clock = clock
        self.responder = responder
        self.inbox: list[tuple[float, bytes]] = []
        self.buffer = b""
        self.writes: list[tuple[float, bytes]] = []

    def _arrive(self) -> None:
        now = self.clock.now
        due = [item for item in self.inbox if item[0] <= now]
        self.inbox = [item for item in self.inbox if item[0] > now]
        for _, data in due:
            self.buffer += data

    def _next(self) -> float | None:
        return min((t for t, _ in self.inbox), default=None)

    def write(self, data: bytes) -> None:
        self.writes.append((self.clock.now, data))
        self.inbox += self.responder(len(self.writes) - 1, data, self.clock.now)
        self.inbox.sort(key=lambda item: item[0])

    def wait_readable(self, timeout: float) -> bool:
        self._arrive()
        if self.buffer:
            return True
        nxt = self._next()
        until = self.clock.now + max(0.0, timeout)
        if nxt is not None and nxt <= until:
            self.clock.now = nxt
            self._arrive()
            return True
        self.clock.now = until
        return False

    def read(self, size: int, deadline: float, limit: int = 0, wait: float | None = None) -> bytes:
        limit = max(size, limit)
        while True:
            self._arrive()
            if len(self.buffer) >= size or self.clock.now >= deadline:
                out, self.buffer = self.buffer[:limit], self.buffer[limit:]
                return out
            nxt = self._next()
            self.clock.now = nxt if nxt is not None and nxt <= deadline else deadline

    def take_input(self, limit: int = 512) -> bytes:
        self._arrive()
        out, self.buffer = self.buffer[:limit], self.buffer[limit:]
        return out

    def read_ready(self, limit: int) -> bytes:
        return self.take_input(limit)

    def transfer(self, frame: bytes, size: int, deadline: float, limit: int, wait: float) -> bytes:
        self.write(frame)
        return self.read(size, deadline, limit)

    def close(self) -> None:
        self.closed = True


def make_line(responder: Responder, **serial: object) -> tuple[RtuLine, ScriptedLink, FakeClock]:
    clock = FakeClock()
    link = ScriptedLink(clock, responder)
    settings_ = SerialSettings(baudrate=BAUD, silence=SILENCE, **serial)  # type: ignore[arg-type]
    return RtuLine(lambda: link, settings_, clock=clock), link, clock


def numbered(n: int, frame: bytes) -> bytes:
    """The answer to request #n: its registers hold n, n+1, ..."""
    return ReadResponse(frame[0], tuple(n + k for k in range(frame[5]))).encode()


def fault_responder(schedule: list[tuple[str, float]], timeout: float) -> Responder:
    """Answers request #n as ``schedule[n]`` (repeated) says: (fault, x in [0, 1) varying its timing). A late
    answer comes after the master's deadline, before the end of a 0.3 s quarantine; bytes after an answer come
    within the silence."""

    def responder(n: int, frame: bytes, at: float) -> list[tuple[float, bytes]]:
        fault, x = schedule[n % len(schedule)]
        answer = numbered(n, frame)
        budget = (len(frame) + len(answer)) * 11 / BAUD + timeout
        soon = at + 0.001 + x * 0.09
        arrivals = {
            "late": [(at + budget + 0.0001 + x * 0.29, answer)],
            "twice": [(soon, answer), (soon + x * SILENCE, answer)],
            "trailing": [(soon, answer), (soon + x * SILENCE, b"\x00")],
            "garbage": [(soon, b"\x02\x03" + answer)],
            "split": [(soon, answer[:3]), (soon + 0.005, answer[3:])],
            "crc": [(soon, answer[:-1] + bytes([answer[-1] ^ 1]))],
            "silent": [],
            "exception": [(soon, ExceptionResponse(2, 3, 2).encode())],
        }
        return arrivals.get(fault, [(soon, answer)])

    return responder


def drive(task: LineTask, late: Callable[[], float] = lambda: 0.0, steps: int = 10_000) -> PollResult | StarterbusError:
    """Advance ``task`` as a poller would: when its line's input is readable (unless its fd is -1) or at
    :attr:`wake_at`, whichever comes first, plus ``late()`` seconds (a poller busy with other lines); returns
    its result or its error."""
    for _ in range(steps):
        link = task.line.link
        assert isinstance(link, ScriptedLink)
        clock = link.clock
        task.advance(clock.now)
        if task.done:
            try:
                return task.result()
            except StarterbusError as exc:
                return exc
        due = task.wake_at
        if task.fd >= 0:  # it waits for its input too
            link._arrive()
            arrival = clock.now if link.buffer else link._next()
            if arrival is not None:
                due = min(due, arrival)
        clock.now = max(clock.now, due) + late()
    raise AssertionError(f"the task is not done after {steps} steps")
