"""The demo fleet, started once per test module that needs it (simulators on ptys, loopback and a virtual bus)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from starterbus.fleet.demo import DemoFleet, start_demo_fleet


@pytest.fixture(scope="module")
def demo() -> Iterator[DemoFleet]:
    fleet = start_demo_fleet(period=0.2)
    try:
        yield fleet
    finally:
        fleet.close()
