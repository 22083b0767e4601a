"""The Transport template: state checks, shared rules, hooks, and declared capabilities against the hooks."""

from __future__ import annotations

from collections.abc import Sequence

import pytest

from starterbus.core.errors import NotOpenError, UnsupportedOperationError
from starterbus.core.model import PointDef, Reading
from starterbus.core.profile import Profile
from starterbus.core.status import Command
from starterbus.core.transport import Capability, Transport
from starterbus.core.url import DeviceUrl
from starterbus.testing.kit_base import is_open

READS = frozenset({Capability.READ_MEASUREMENTS, Capability.READ_PARAMETERS})


class Counting(Transport):
    name = "counting"

    def __init__(self, profile: Profile, caps: frozenset[Capability] = READS) -> None:
        super().__init__(DeviceUrl.parse("counting://here"), profile)
        self.caps = caps
        self.opened = self.closed = 0
        self.asked: list[list[str]] = []

    def _open(self) -> None:
        self.opened += 1

    def _close(self) -> None:
        self.closed += 1

    @property
    def capabilities(self) -> frozenset[Capability]:
        return self.caps

    def _read_points(self, points: Sequence[PointDef]) -> list[Reading]:
        self.asked.append([p.key for p in points])
        return [Reading(p, 0) for p in points]


def test_the_state_is_checked_before_any_hook(jjr5000: Profile) -> None:
    transport = Counting(jjr5000)
    point = jjr5000.point("phase_a_current")
    with pytest.raises(NotOpenError, match=r"counting counting://here is not open: call open\(\)"):
        transport.read_points([point])
    transport.open()
    transport.open()
    assert transport.opened == 1 and is_open(transport)
    assert transport.read_points([]) == [] and transport.asked == [], "no points: no request"
    assert [r.point for r in transport.read_points([point])] == [point]
    transport.close()
    transport.close()
    assert transport.closed == 1 and not is_open(transport)
    with pytest.raises(NotOpenError, match=r"not open \(closed\)"):
        transport.read_points([point])
    with transport:
        assert transport.opened == 2
    assert transport.closed == 2


def test_a_capability_not_declared_is_refused_before_the_hook(jjr5000: Profile) -> None:
    transport = Counting(jjr5000, frozenset({Capability.READ_MEASUREMENTS}))
    with transport:
        with pytest.raises(UnsupportedOperationError, match="read parameters such as ramp_time.*it offers: read-m"):
            transport.read_points([jjr5000.point("phase_a_current"), jjr5000.point("ramp_time")])
        with pytest.raises(UnsupportedOperationError, match="cannot send the command 'start'"):
            transport.send_command(Command.START)
        with pytest.raises(UnsupportedOperationError, match="read the status"):
            transport.poll([], status=True)
        with pytest.raises(UnsupportedOperationError, match="identify"):
            transport.identify()
    assert transport.asked == []


def test_declared_capabilities_and_overridden_hooks_must_agree() -> None:
    assert Counting.capability_problems(READS) == []
    assert Counting.capability_problems(frozenset({Capability.READ_MEASUREMENTS})) == []
    assert Counting.capability_problems(frozenset({Capability.STATUS, *READS})) == [
        "status is declared but _read_status() is not overridden"
    ]
    assert Counting.capability_problems(frozenset()) == [
        "_read_points() is overridden but no capability it serves is declared"
    ]


def test_overriding_a_template_method_is_refused_with_the_hook_to_use() -> None:
    with pytest.raises(TypeError, match=r"overrides read_status\(\).*override the hook _read_status\(\)"):

        class Old(Counting):
            def read_status(self) -> object:  # type: ignore[override]
                return None
