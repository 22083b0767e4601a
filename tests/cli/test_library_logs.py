"""The libraries' own logs stay off the CLI's stderr unless asked for with ``-v`` (cli/logs.py).

The error is real: the Profibus gateway transport talks to its gateway through pymodbus, and pymodbus logs an
ERROR of its own when the connection is refused. Without ``-v`` stderr holds only starterbus's one line."""

from __future__ import annotations

import logging
import socket
import subprocess
import sys
from collections.abc import Iterator

import pytest

from starterbus.cli.logs import LIBRARY_LOGGERS, SILENT, configure_logging


def closed_port() -> int:
    """A local TCP port nothing listens on (bound, then released: connections are refused)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def status(*options: str) -> subprocess.CompletedProcess[str]:
    url = f"profibus-pkw+gateway://127.0.0.1:{closed_port()}?ppo=1&timeout=0.3"
    return subprocess.run(
        [sys.executable, "-m", "starterbus.cli.main", *options, "status", url, "--model", "jjr8000"],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip


def test_a_pymodbus_error_shows_only_starterbus_one_line() -> None:
    done = status()
    assert done.returncode == 1 and done.stdout == ""
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("starterbus: error: gateway 127.0.0.1:"), done.stderr
    assert "pymodbus" not in done.stderr.replace("ModbusTcpClient", "")


def test_verbose_shows_the_library_log_before_the_error() -> None:
    done = status("-v")
    assert done.returncode == 1
    lines = done.stderr.splitlines()
    assert any(line.startswith("pymodbus") and "Connection refused" in line for line in lines), done.stderr
    assert lines[-1].startswith("starterbus: error: gateway 127.0.0.1:")


@pytest.fixture
def library_levels() -> Iterator[None]:
    saved = {name: logging.getLogger(name).level for name in LIBRARY_LOGGERS}
    yield
    for name, level in saved.items():
        logging.getLogger(name).setLevel(level)


@pytest.mark.usefixtures("library_levels")
def test_every_library_logger_is_silenced_without_verbose() -> None:
    configure_logging(0)
    for name in LIBRARY_LOGGERS:
        assert not logging.getLogger(name).isEnabledFor(logging.CRITICAL), name
        assert not logging.getLogger(f"{name}.child").isEnabledFor(logging.CRITICAL), name
    assert SILENT > logging.CRITICAL
