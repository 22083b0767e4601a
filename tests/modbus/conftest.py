"""Modbus RTU test helpers: the golden vector table, raw pty peers, simulators that are always closed.

``VECTORS`` is docs/manuals.md#modbus-golden-vectors and docs/manuals.md#jjr8000-modbus-worked-examples, byte
for byte: the JJR5000/SSD1 examples with their printed CRC, the JJR8000 examples (printed without CRC) with the
CRC appended. Any test with a ``golden`` argument runs once per row (``pytest_generate_tests``), so the encoder
and decoder tests share one table.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import pytest

from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.transports.modbus.codec.frames import (
    ReadRequest,
    ReadResponse,
    Request,
    Response,
    WriteRequest,
    WriteResponse,
)
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator
from starterbus.transports.modbus.transport.rtu import LINES


def h(text: str) -> bytes:
    return bytes.fromhex(text)


@dataclass(frozen=True)
class Vector:
    """One manual example: the request, the response as printed, and what each decodes to."""

    id: str
    models: tuple[str, ...]
    source: str
    request_frame: bytes
    request: Request
    response_frame: bytes
    response: Response | None  # None: the manual's response is malformed (a DecodeError, never a value)
    malformed_field: str = ""  # the DecodeError's field for a malformed response
    register: int = 0  # the register read or written
    engineering: float | int | None = None  # the value a client reports
    status: str = ""  # for status word reads: the decoded state


VECTORS: tuple[Vector, ...] = (
    Vector(
        "jjr5000-read-rated-current", ("jjr5000", "ssd1"),
        "jjr5000-modbus-rtu / ssd1-modbus-rtu, FC03 example (CRC printed)",
        h("02 03 01 00 00 01 85 C5"), ReadRequest(2, 0x0100, 1),
        h("02 03 02 01 86 7C 76"), ReadResponse(2, (0x0186,)),
        register=0x0100, engineering=390,
    ),
    Vector(
        "jjr5000-write-current-limit", ("jjr5000", "ssd1"),
        "jjr5000-modbus-rtu / ssd1-modbus-rtu, FC06 example (CRC printed)",
        h("02 06 01 03 01 7C 78 74"), WriteRequest(2, 0x0103, 0x017C),
        h("02 06 01 03 01 7C 78 74"), WriteResponse(2, 0x0103, 0x017C),
        register=0x0103, engineering=380,
    ),
    Vector(
        "jjr8000-start", ("jjr8000",), "jjr8000 manual 1.2 4) example 1 (CRC appended; the reply is not an echo)",
        h("02 06 00 00 00 09 49 FF"), WriteRequest(2, 0x0000, 0x0009),
        h("02 06 00 00 00 00 89 F9"), None, malformed_field="echo", register=0x0000,
    ),
    Vector(
        "jjr8000-status-starting", ("jjr8000",), "jjr8000 manual example 2, first reply",
        h("02 03 00 01 00 01 D5 F9"), ReadRequest(2, 0x0001, 1),
        h("02 03 02 01 00 FD D4"), ReadResponse(2, (0x0100,)),
        register=0x0001, status="starting",
    ),
    Vector(
        "jjr8000-status-fault-6", ("jjr8000",), "jjr8000 manual example 2, second reply (fault 6 motor overload)",
        h("02 03 00 01 00 01 D5 F9"), ReadRequest(2, 0x0001, 1),
        h("02 03 02 81 06 1C 16"), ReadResponse(2, (0x8106,)),
        register=0x0001, status="fault 6 motor overload",
    ),
    Vector(
        "jjr8000-phase-a-current", ("jjr8000",), "jjr8000 manual example 3 (23.5 A)",
        h("02 03 00 02 00 01 25 F9"), ReadRequest(2, 0x0002, 1),
        h("02 03 02 00 EB BC 0B"), ReadResponse(2, (0x00EB,)),
        register=0x0002, engineering=23.5,
    ),
    Vector(
        "jjr8000-read-current-limit", ("jjr8000",), "jjr8000 manual example 4 (350 = 3.50 x In)",
        h("02 03 01 07 00 01 34 04"), ReadRequest(2, 0x0107, 1),
        h("02 03 02 01 5E 7C 2C"), ReadResponse(2, (0x015E,)),
        register=0x0107, engineering=3.5,
    ),
    Vector(
        "jjr8000-write-rated-current", ("jjr8000",), "jjr8000 manual example 5 (reply printed malformed)",
        h("02 06 01 00 01 90 89 F9"), WriteRequest(2, 0x0100, 400),
        h("02 06 02 01 90 FD 74"), None, malformed_field="length", register=0x0100,
    ),
    Vector(
        "jjr8000-write-rise-time", ("jjr8000",), "jjr8000 manual example 6 (reply printed malformed)",
        h("02 06 01 03 00 14 78 0A"), WriteRequest(2, 0x0103, 20),
        h("02 06 02 00 14 FC 87"), None, malformed_field="length", register=0x0103,
    ),
)  # fmt: skip


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "golden" in metafunc.fixturenames:
        metafunc.parametrize("golden", VECTORS, ids=[v.id for v in VECTORS])


@pytest.fixture
def vectors() -> tuple[Vector, ...]:
    return VECTORS


# -- isolation ------------------------------------------------------------------------------------------------


@pytest.fixture(autouse=True)
def _no_line_left_open(monkeypatch: pytest.MonkeyPatch, tmp_path: object) -> Iterator[None]:
    """Every test closes the lines it opened (like python-can's channel check); audit logs go to tmp."""
    monkeypatch.setenv("STARTERBUS_AUDIT_LOG", str(tmp_path) + "/audit.jsonl")
    yield
    leaked = list(LINES._items)
    for key in leaked:
        while LINES.users(key):
            LINES.release(key)
    assert not leaked, f"lines left open: {leaked}"


# -- raw pty peers ----------------------------------------------------------------------------------------------


class PtyPeer:
    """The master side of a fresh pty; a client opens :attr:`path`. The test scripts what the 'device' says."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.received: list[bytes] = []
        self.arrivals: list[float] = []
        self.replied_at: list[float] = []  # after the answer's last write returned
        # before that last write began: the answer's last byte went out after it, so "the master kept the silence
        # after it" is checked against this time, whenever the peer's own thread was held up (a loaded machine)
        self.last_write_from: list[float] = []
        self._thread: threading.Thread | None = None

    def read_frame(self, size: int = 8, timeout: float = 3.0) -> bytes:
        data = b""
        deadline = time.monotonic() + timeout
        while len(data) < size:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            ready, _, _ = select.select([self.master], [], [], remaining)
            if not ready:
                break
            data += os.read(self.master, size - len(data))
        return data

    def pending(self, wait: float = 0.05) -> bytes:
        """Whatever the client sent that nobody read (waits a little for stragglers)."""
        data = b""
        while select.select([self.master], [], [], wait)[0]:
            data += os.read(self.master, 4096)
        return data

    def write(self, data: bytes) -> None:
        os.write(self.master, data)

    def serve(self, script: Sequence[bytes | Sequence[bytes | float] | None], wait: float = 3.0) -> None:
        """In a thread: for each entry, read one 8-byte request, then answer: bytes, nothing (None), or a
        sequence of byte strings and pauses (seconds) for split or slow answers. Stops when no request
        comes for ``wait`` seconds."""

        def run() -> None:
            for reply in script:
                request = self.read_frame(timeout=wait)
                if not request:
                    return
                self.received.append(request)
                self.arrivals.append(time.monotonic())
                if reply is None:
                    continue
                parts = [reply] if isinstance(reply, bytes) else list(reply)
                began = time.monotonic()
                for part in parts:
                    if isinstance(part, float):
                        time.sleep(part)
                    else:
                        began = time.monotonic()
                        self.write(part)
                self.last_write_from.append(began)
                self.replied_at.append(time.monotonic())

        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()

    def join(self) -> None:
        if self._thread is not None:
            self._thread.join(timeout=5)

    def close(self) -> None:
        self.join()
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


@pytest.fixture
def peer() -> Iterator[PtyPeer]:
    p = PtyPeer()
    yield p
    p.close()


# -- simulators ---------------------------------------------------------------------------------------------------


SimFactory = Callable[..., ModbusRtuSimulator]


@pytest.fixture
def make_sim() -> Iterator[SimFactory]:
    """``make_sim(model, units=(2,), **kwargs)``: a started simulator (pty by default), closed after the test."""
    started: list[ModbusRtuSimulator] = []

    def factory(model: str | Profile, units: Sequence[int] = (2,), **kwargs: object) -> ModbusRtuSimulator:
        profile = model if isinstance(model, Profile) else get_profile(model)
        starters = {unit: SimulatedStarter(profile) for unit in units}
        if not {"pty", "port", "tcp"} & set(kwargs):
            kwargs["pty"] = True
        sim = ModbusRtuSimulator(starters, **kwargs)  # type: ignore[arg-type]
        started.append(sim)
        return sim.start()

    yield factory
    for sim in started:
        sim.close()
