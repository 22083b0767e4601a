"""Profibus PKW/PZD test helpers: the golden vectors of
docs/manuals.md#profibus-golden-vectors, and simulators that always close.

``VECTORS`` is every telegram half the manuals print (jjr5000-profibus-dp.zh.txt "应用实例" and
jjr8000-modbus-profibus-devicenet.zh.txt section 2 "应用实例"), byte for byte, with what it decodes to. Any test
with a ``golden`` argument runs once per row; ``PAIRS`` are the request/response pairs the simulated slave must
answer with exactly the printed bytes.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import pytest

from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.simulator import ManualClock, SimulatedStarter
from starterbus.transports.profibus_pkw.codec.codes import Direction, Part, ResponseCode, TaskCode
from starterbus.transports.profibus_pkw.codec.telegram import PkwRequest, PkwResponse, PzdIn, PzdOut, Telegram
from starterbus.transports.profibus_pkw.driver.channels import GATEWAYS, attached_slaves, detach_slave
from starterbus.transports.profibus_pkw.simulator import ProfibusGatewaySimulator


def h(text: str) -> bytes:
    return bytes.fromhex(text)


@dataclass(frozen=True)
class Vector:
    """One printed telegram half and its meaning."""

    id: str
    model: str
    source: str
    direction: Direction
    part: Part
    data: bytes
    telegram: Telegram
    code: int | None = None  # task (out) or response (in) code of a PKW half
    indl: int | None = None
    key: str | None = None  # the point INDL names (PKW) with this model
    value: float | int | None = None  # engineering value of PWE (PKW value) or of ACT (PZD, A)
    error: str | None = None  # the model's meaning of the error number (response 3)
    status: dict[str, object] = field(default_factory=dict)  # Status attributes (PZD in)


J5 = "jjr5000-profibus-dp.zh.txt 应用实例"
J8 = "jjr8000-modbus-profibus-devicenet.zh.txt 2 应用实例"

VECTORS: tuple[Vector, ...] = (
    # JJR5000, station 2
    Vector("5000-pzd-start-out", "jjr5000", J5, Direction.OUT, Part.PZD, h("00 0B 00 00"), PzdOut(0x000B, 0)),
    Vector(
        "5000-pzd-start-in", "jjr5000", J5, Direction.IN, Part.PZD, h("09 00 03 C0"), PzdIn(0x0900, 0x03C0),
        value=96.0, status={"starting": True, "fault": False, "unknown_bits": 0x0800},
    ),
    Vector(
        "5000-pzd-fault-in", "jjr5000", J5, Direction.IN, Part.PZD, h("81 05 05 64"), PzdIn(0x8105, 0x0564),
        value=138.0, status={"fault": True, "fault_code": 5, "fault_text": "mains phase loss", "starting": True},
    ),
    Vector(
        "5000-pkw-read-param-out", "jjr5000", J5, Direction.OUT, Part.PKW, h("01 02 00 00"), PkwRequest(0x0102, 0),
        code=TaskCode.READ_PARAMETER, indl=0x02, key="soft_stop_time",
    ),
    Vector(
        "5000-pkw-read-param-in", "jjr5000", J5, Direction.IN, Part.PKW, h("01 02 00 0C"), PkwResponse(0x0102, 12),
        code=ResponseCode.VALUE, indl=0x02, key="soft_stop_time", value=12,
    ),
    Vector(
        "5000-pkw-write-out", "jjr5000", J5, Direction.OUT, Part.PKW, h("02 03 01 5E"), PkwRequest(0x0203, 350),
        code=TaskCode.WRITE_PARAMETER, indl=0x03, key="current_limit", value=350,
    ),
    Vector(
        "5000-pkw-write-in", "jjr5000", J5, Direction.IN, Part.PKW, h("01 03 01 5E"), PkwResponse(0x0103, 350),
        code=ResponseCode.VALUE, indl=0x03, key="current_limit", value=350,
    ),
    Vector(
        "5000-pkw-write-refused", "jjr5000", J5, Direction.IN, Part.PKW, h("03 03 00 03"), PkwResponse(0x0303, 3),
        code=ResponseCode.CANNOT_EXECUTE, indl=0x03, error="illegal data value",
    ),
    Vector(
        "5000-pkw-read-meas-out", "jjr5000", J5, Direction.OUT, Part.PKW, h("03 03 00 00"), PkwRequest(0x0303, 0),
        code=TaskCode.READ_MEASUREMENT, indl=0x03, key="phase_b_current",
    ),
    Vector(
        "5000-pkw-read-meas-in", "jjr5000", J5, Direction.IN, Part.PKW, h("01 03 02 64"), PkwResponse(0x0103, 612),
        code=ResponseCode.VALUE, indl=0x03, key="phase_b_current", value=61.2,
    ),
    # JJR8000, station 2
    Vector("8000-pzd-start-out", "jjr8000", J8, Direction.OUT, Part.PZD, h("00 09 00 00"), PzdOut(0x0009, 0)),
    Vector(
        "8000-pzd-start-in", "jjr8000", J8, Direction.IN, Part.PZD, h("09 00 03 C0"), PzdIn(0x0900, 0x03C0),
        value=96.0, status={"starting": True, "fault": False, "unknown_bits": 0x0800},
    ),
    Vector(
        "8000-pzd-fault-in", "jjr8000", J8, Direction.IN, Part.PZD, h("81 01 05 64"), PzdIn(0x8101, 0x0564),
        value=138.0, status={"fault": True, "fault_code": 1, "fault_text": "mains phase loss"},
    ),
    Vector(
        "8000-pkw-read-param-out", "jjr8000", J8, Direction.OUT, Part.PKW, h("01 03 00 00"), PkwRequest(0x0103, 0),
        code=TaskCode.READ_PARAMETER, indl=3, key="ramp_time",
    ),
    Vector(
        "8000-pkw-read-param-in", "jjr8000", J8, Direction.IN, Part.PKW, h("01 03 00 0C"), PkwResponse(0x0103, 12),
        code=ResponseCode.VALUE, indl=3, key="ramp_time", value=12,
    ),
    Vector(
        "8000-pkw-write-out", "jjr8000", J8, Direction.OUT, Part.PKW, h("02 07 01 5E"), PkwRequest(0x0207, 350),
        code=TaskCode.WRITE_PARAMETER, indl=7, key="current_limit", value=3.5,
    ),
    Vector(
        "8000-pkw-write-in", "jjr8000", J8, Direction.IN, Part.PKW, h("01 07 01 5E"), PkwResponse(0x0107, 350),
        code=ResponseCode.VALUE, indl=7, key="current_limit", value=3.5,
    ),
    Vector(
        "8000-pkw-write-refused", "jjr8000", J8, Direction.IN, Part.PKW, h("03 07 00 03"), PkwResponse(0x0307, 3),
        code=ResponseCode.CANNOT_EXECUTE, indl=7, error="cannot modify while running",
    ),
    Vector(
        "8000-pkw-read-meas-out", "jjr8000", J8, Direction.OUT, Part.PKW, h("03 03 00 00"), PkwRequest(0x0303, 0),
        code=TaskCode.READ_MEASUREMENT, indl=3, key="phase_b_current",
    ),
    Vector(
        "8000-pkw-read-meas-in", "jjr8000", J8, Direction.IN, Part.PKW, h("01 03 02 64"), PkwResponse(0x0103, 612),
        code=ResponseCode.VALUE, indl=3, key="phase_b_current", value=61.2,
    ),
)  # fmt: skip


@dataclass(frozen=True)
class Pair:
    """A PKW request and the response the manual prints for it, and the starter state that produces it."""

    id: str
    model: str
    request: bytes
    response: bytes
    running: bool = False
    values: dict[str, int] = field(default_factory=dict)
    note: str = ""


PAIRS: tuple[Pair, ...] = (
    Pair("5000-read-param", "jjr5000", h("01 02 00 00"), h("01 02 00 0C"), values={"soft_stop_time": 12}),
    Pair("5000-write", "jjr5000", h("02 03 01 5E"), h("01 03 01 5E")),
    Pair(
        "5000-write-refused", "jjr5000", h("02 03 01 F5"), h("03 03 00 03"),
        note="the manual's refusal answer, provoked with 501 % (above 150-500 %)",
    ),
    Pair("5000-read-meas", "jjr5000", h("03 03 00 00"), h("01 03 02 64"), running=True),
    Pair("8000-read-param", "jjr8000", h("01 03 00 00"), h("01 03 00 0C"), values={"ramp_time": 12}),
    Pair("8000-write", "jjr8000", h("02 07 01 5E"), h("01 07 01 5E")),
    Pair("8000-write-refused", "jjr8000", h("02 07 01 5E"), h("03 07 00 03"), running=True),
    Pair("8000-read-meas", "jjr8000", h("03 03 00 00"), h("01 03 02 64"), running=True),
)  # fmt: skip


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "golden" in metafunc.fixturenames:
        metafunc.parametrize("golden", VECTORS, ids=[v.id for v in VECTORS])
    if "pair" in metafunc.fixturenames:
        metafunc.parametrize("pair", PAIRS, ids=[p.id for p in PAIRS])


def make_running_starter(profile: Profile, clock: ManualClock, **values: int) -> SimulatedStarter:
    """A starter whose motor runs at 61.2 A (rated 612 A, load 0.1): the manual's phase B example."""
    starter = SimulatedStarter(profile, clock, load=0.1, values={"motor_rated_current": 612, **values})
    starter.write_control_word(0x0009)
    clock.advance(600)
    assert starter.status_word() & 0x0200, "the motor should run"
    return starter


RunningStarter = Callable[..., SimulatedStarter]


@pytest.fixture
def running_starter() -> RunningStarter:
    return make_running_starter


@pytest.fixture
def vectors() -> tuple[Vector, ...]:
    return VECTORS


@pytest.fixture
def pairs() -> tuple[Pair, ...]:
    return PAIRS


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock(1000.0)


@pytest.fixture
def profiles() -> dict[str, Profile]:
    return {"jjr5000": get_profile("jjr5000"), "jjr8000": get_profile("jjr8000")}


@pytest.fixture
def gateway_factory() -> Iterator[type[ProfibusGatewaySimulator]]:
    """Start gateway simulators through this; every one is closed after the test."""
    started: list[ProfibusGatewaySimulator] = []

    class Tracked(ProfibusGatewaySimulator):
        def start(self, timeout: float = 5.0) -> ProfibusGatewaySimulator:
            started.append(self)
            return super().start(timeout)

    yield Tracked
    for sim in started:
        sim.close()


@pytest.fixture(autouse=True)
def _nothing_left_open() -> Iterator[None]:
    """Every test detaches its slaves, closes its links (cycle threads) and releases its gateway connections."""
    before = set(attached_slaves())
    open_before = set(GATEWAYS.leases())  # (the pool is modbus-tcp's too: what another test left is not this one's)
    yield
    for name in set(attached_slaves()) - before:
        detach_slave(name)
    left = set(GATEWAYS.leases()) - open_before
    assert not left, f"gateway connections left open: {sorted(map(str, left))}"
    cycling = [t.name for t in threading.enumerate() if t.name.startswith("profibus-pkw cycle")]
    assert not cycling, f"cycle threads left running: {cycling}"
