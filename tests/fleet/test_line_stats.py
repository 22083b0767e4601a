"""Wire counters add up per line; utilisation is time on the wire over the elapsed time."""

from __future__ import annotations

import pytest

from starterbus.core.transport import TransportCounters
from starterbus.fleet.line_stats import LineStats


def test_counters_add_subtract_and_copy() -> None:
    a = TransportCounters(1, 3, 2, 1, 1, 24, 13, 0.5, 0.25)
    b = a.copy()
    b.add(a)
    assert b.minus(a) == a
    assert b == TransportCounters(2, 6, 4, 2, 2, 48, 26, 1.0, 0.5)
    assert a.as_json()["bytes_sent"] == 24
    assert set(a.as_json()) == {
        "transactions", "requests", "retries", "timeouts", "errors", "bytes_sent", "bytes_received", "busy_time",
        "wire_time",
    }  # fmt: skip


def test_line_stats_snapshot_and_utilisation() -> None:
    stats = LineStats("rtu", started=100.0)
    stats.wire.add(TransportCounters(transactions=4, requests=4, busy_time=1.0, wire_time=0.5))
    shot = stats.snapshot(now=104.0)
    assert shot.elapsed == 4.0
    assert shot.utilisation == pytest.approx(0.25)
    assert shot.wire_utilisation == pytest.approx(0.125)
    stats.wire.add(TransportCounters(transactions=1))
    assert shot.wire.transactions == 4, "a snapshot is a copy"
    stats.stopped = 102.0
    assert stats.snapshot(now=200.0).elapsed == 2.0
    assert LineStats("idle", started=5.0).snapshot(5.0).utilisation == 0.0
