"""Fixtures of the engine tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from starterbus.core.scheduler import Scheduler


@pytest.fixture
def loop() -> Iterator[Scheduler]:
    """A scheduler of the test's own (not the process's), stopped afterwards."""
    sched = Scheduler()
    yield sched
    sched.stop()
