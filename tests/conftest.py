"""Shared fixtures: the built-in profiles and a deterministic clock."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import textwrap
import types
from pathlib import Path

import pytest
from hypothesis import settings

from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.simulator import ManualClock


def _tests_importable() -> None:
    """Helpers shared between test files import as ``starterbus.tests...`` (the repository root is the package);
    a regular install does not ship the tests, so name this folder as that package when it is missing."""
    if importlib.util.find_spec("starterbus.tests") is None:
        package = types.ModuleType("starterbus.tests")
        package.__path__ = [str(Path(__file__).parent)]
        sys.modules["starterbus.tests"] = package


_tests_importable()

# No timing assertions (speed is measured in bench/): hypothesis's per-example deadline (200 ms) is one, and a
# loaded machine exceeded it (test_codec's test_receiver_any_chunking beside two busy processes). The examples
# themselves, their number and every other setting are unchanged.
settings.register_profile("starterbus", deadline=None)
settings.load_profile("starterbus")


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


class ThirdParty:
    """Installed-looking third-party distributions (dist-info + entry points) and the real CLI run with them."""

    @staticmethod
    def make_dist(root: Path, dist: str, module: str, entry_points: str, files: dict[str, str]) -> None:
        pkg = root / module
        pkg.mkdir(parents=True)
        for name, text in files.items():
            (pkg / name).write_text(text, encoding="utf-8")
        info = root / f"{dist}-1.0.dist-info"
        info.mkdir()
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 1.0\n", encoding="utf-8")
        (info / "entry_points.txt").write_text(textwrap.dedent(entry_points), encoding="utf-8")

    @staticmethod
    def run_cli(*args: str, path: Path) -> subprocess.CompletedProcess[str]:
        """``starterbus ARGS`` in a subprocess with ``path`` (the distributions) on PYTHONPATH."""
        env = dict(os.environ, PYTHONPATH=str(path))
        return subprocess.run(
            [sys.executable, "-m", "starterbus.cli.main", *args],
            capture_output=True,
            text=True,
            env=env,
            timeout=60,
            check=False,
        )


@pytest.fixture(scope="session")
def third_party() -> type[ThirdParty]:
    return ThirdParty
