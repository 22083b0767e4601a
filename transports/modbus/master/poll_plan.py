"""Modbus RTU poll plans: the fewest FC03 requests, by wire time, that read a device's status and points.

A plan is computed once per (points, status) and kept by the transport. Every register is read once per poll:
the status (status word + phase currents) and the points asked for are one set of registers. Adjacent
registers are merged up to the model's ``max_read_registers``; a gap is read along (its values dropped) when
that costs less wire time than a second request and every register of the gap is one the profile defines (a
range that covers an undefined register answers exception 02). The choice is exact: a shortest path over the
sorted registers, each step one request, weighted by its wire time.

Wire time of one FC03 for ``n`` registers, at 11 bits a character: the 8-byte request, the silent interval, the
``5 + 2n``-byte answer, the silent interval before the next request. A separate request therefore costs 13
characters plus two silences (at least 7 characters) more than reading its registers along with another: a gap
of up to about 10 registers is worth reading along, where the model's limit allows.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence, Set
from dataclasses import dataclass
from operator import attrgetter

from starterbus.core import (
    PlannedRequest,
    PointDef,
    PollResult,
    Profile,
    Status,
    UnsupportedOperationError,
    readings,
    status_with_currents,
)
from starterbus.transports.modbus.codec.timing import char_time
from starterbus.transports.modbus.settings import PROTOCOL, TRANSPORT

_KEY = attrgetter("key")

REQUEST_BYTES = 8  # unit, function, address (2), count (2), CRC (2)
ANSWER_OVERHEAD = 5  # unit, function, byte count, CRC (2)


def fc03_wire_time(count: int, char: float, silence: float) -> float:
    """Seconds one FC03 of ``count`` registers occupies the line, both silences included."""
    return (REQUEST_BYTES + ANSWER_OVERHEAD + 2 * count) * char + 2 * silence


def cover(needed: Sequence[int], readable: Set[int], limit: int, char: float, silence: float) -> list[tuple[int, int]]:
    """(start, count) requests reading every register of ``needed`` in the least wire time.

    A request spans at most ``limit`` registers and reads a register not in ``needed`` only if ``readable``.
    """
    wanted = sorted(set(needed))
    n = len(wanted)
    best = [0.0] + [float("inf")] * n  # best[j]: least wire time for wanted[:j]
    step = [0] * (n + 1)  # step[j]: where the last request of that best cover starts
    for j in range(n):
        for i in range(j, -1, -1):
            span = wanted[j] - wanted[i] + 1
            if span > limit:
                break
            if i < j and wanted[i + 1] - wanted[i] > 1 and not _gap_readable(wanted[i], wanted[i + 1], readable):
                break  # every longer span reaching further back crosses this gap too
            cost = best[i] + fc03_wire_time(span, char, silence)
            if cost < best[j + 1]:
                best[j + 1], step[j + 1] = cost, i
    requests: list[tuple[int, int]] = []
    j = n
    while j > 0:
        i = step[j]
        requests.append((wanted[i], wanted[j - 1] - wanted[i] + 1))
        j = i
    return requests[::-1]


def _gap_readable(low: int, high: int, readable: Set[int]) -> bool:
    return all(address in readable for address in range(low + 1, high))


@dataclass(frozen=True, slots=True)
class PollPlan:
    """The requests of one poll and where each wanted value sits in their answers, one after another."""

    requests: tuple[tuple[int, int], ...]
    status_at: tuple[int, ...]  # status word, then the phase currents; empty: no status asked
    points_at: tuple[int, ...]  # one per point asked, in the order asked
    names: tuple[tuple[str, ...], ...]  # per request: the keys it carries (for display)


class PollPlans:
    """The plans of one device (one transport), computed on first use and kept."""

    def __init__(self, profile: Profile, limit: int, baudrate: int, silence: float) -> None:
        self.profile = profile
        self.limit = limit
        self.char = char_time(baudrate)
        self.silence = silence
        self.baudrate = baudrate
        self.readable = frozenset(a for p in profile.points.values() if (a := p.address_for(PROTOCOL)) is not None)
        self._plans: dict[tuple[tuple[str, ...], bool], PollPlan] = {}

    def get(self, points: Sequence[PointDef], status: bool) -> PollPlan:
        key = (tuple(map(_KEY, points)), status)
        plan = self._plans.get(key)
        if plan is None:
            plan = self._plans[key] = self._make(points, status)
        return plan

    def _address(self, point: PointDef) -> int:
        address: int | None = point.address_for(PROTOCOL)
        if address is None:
            raise UnsupportedOperationError(f"{self.profile.display_name} {point.key} has no Modbus register")
        return address

    def status_points(self) -> list[PointDef]:
        status_point = self.profile.role("status_word")
        if status_point is None:
            raise UnsupportedOperationError(f"{self.profile.display_name} has no status word")
        return [status_point, *self.profile.phase_currents()]

    def _make(self, points: Sequence[PointDef], status: bool) -> PollPlan:
        status_addresses = [self._address(p) for p in self.status_points()] if status else []
        point_addresses = [self._address(p) for p in points]
        requests = cover(status_addresses + point_addresses, self.readable, self.limit, self.char, self.silence)
        position: dict[int, int] = {}
        for start, count in requests:
            for address in range(start, start + count):
                position[address] = len(position)
        keys: dict[int, list[str]] = {}
        for point in (*self.status_points(), *points) if status else points:
            keys.setdefault(self._address(point), []).append(point.key)
        names = tuple(
            tuple(dict.fromkeys(k for a in range(start, start + count) for k in keys.get(a, ())))
            for start, count in requests
        )
        return PollPlan(
            tuple(requests),
            tuple(position[a] for a in status_addresses),
            tuple(position[a] for a in point_addresses),
            names,
        )

    def describe(self, plan: PollPlan, unit: int) -> list[PlannedRequest]:
        return [
            PlannedRequest(
                f"unit {unit} FC03 0x{start:04X} x{count}: {', '.join(names) or '-'}",
                count,
                REQUEST_BYTES,
                ANSWER_OVERHEAD + 2 * count,
                fc03_wire_time(count, self.char, self.silence),
            )
            for (start, count), names in zip(plan.requests, plan.names, strict=True)
        ]


def decode_status(profile: Profile, words: Sequence[int], source: str, transport: str = TRANSPORT) -> Status:
    """The status from the status word and the phase currents (``words``, in that order); ``transport`` tags
    the currents."""
    return status_with_currents(profile, words[0], words[1:], source=source, current_source=transport)


def run(
    read_registers: Callable[[int, int], tuple[int, ...]],
    plan: PollPlan,
    points: Sequence[PointDef],
    profile: Profile,
    source: str,
) -> PollResult:
    """Send the plan's requests through ``read_registers(start, count)`` and sort the answers out."""
    values: tuple[int, ...] = ()
    for start, count in plan.requests:
        values += read_registers(start, count)
    return sort_out(plan, values, points, profile, source)


def sort_out(
    plan: PollPlan,
    values: Sequence[int],
    points: Sequence[PointDef],
    profile: Profile,
    source: str,
    transport: str = TRANSPORT,
) -> PollResult:
    """The poll's result from the ``values`` of the plan's answers, one after another."""
    value = values.__getitem__
    status = None
    if plan.status_at:
        status = decode_status(profile, list(map(value, plan.status_at)), source, transport)
    if len(points) != len(plan.points_at):
        raise ValueError(f"{len(points)} points for a plan of {len(plan.points_at)}")
    return PollResult(status, readings(points, map(value, plan.points_at)))
