"""Shared fixtures: the built-in profiles and a deterministic clock."""

from __future__ import annotations

from pathlib import Path

import pytest

from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.simulator import ManualClock


@pytest.fixture(params=["jjr5000", "ssd1", "jjr8000"])
def any_profile(request: pytest.FixtureRequest) -> Profile:
    return get_profile(request.param)


@pytest.fixture
def jjr5000() -> Profile:
    return get_profile("jjr5000")


@pytest.fixture
def ssd1() -> Profile:
    return get_profile("ssd1")


@pytest.fixture
def jjr8000() -> Profile:
    return get_profile("jjr8000")


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock(1000.0)


@pytest.fixture(autouse=True)
def _audit_log_in_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Writes and commands are audited: keep every test's audit trail out of the user's home."""
    path = tmp_path / "audit.jsonl"
    monkeypatch.setenv("STARTERBUS_AUDIT_LOG", str(path))
    return path
