"""Shared fixtures of the plugin's tests: a unique virtual CAN channel per test, audit logs kept in tmp."""

from __future__ import annotations

import itertools
import os
from pathlib import Path

import pytest

_channels = itertools.count()


@pytest.fixture
def channel() -> str:
    """A virtual CAN channel no other test uses."""
    return f"co-{os.getpid()}-{next(_channels)}"


@pytest.fixture(autouse=True)
def _audit_log_in_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    path = tmp_path / "audit.jsonl"
    monkeypatch.setenv("STARTERBUS_AUDIT_LOG", str(path))
    return path
