"""Fixtures for the DeviceNet tests: unique virtual channels, checked closed after each test."""

from __future__ import annotations

import uuid
from collections.abc import Iterator

import pytest
from can.interfaces import virtual
from starterbus.transports.devicenet.transport import SCANNERS


@pytest.fixture
def channel(request: pytest.FixtureRequest) -> Iterator[str]:
    """A virtual CAN channel no other test uses; the test must leave no bus open on it."""
    name = f"dn-{request.node.name[:30]}-{uuid.uuid4().hex[:6]}"
    yield name
    key = ("virtual", name)
    assert SCANNERS.users(key) == 0, f"a scanner on {name} was left open"
    assert name not in virtual.channels, f"a python-can bus on {name} was left open"
