"""The libraries' own logs stay off the CLI's stderr unless asked for with ``-v`` (cli/logs.py).

The error is real: the simulated Profibus gateway is a pymodbus server, and pymodbus logs a WARNING of its own when
its port is taken. Without ``-v`` stderr holds only starterbus's one line. (The gateway transport itself no longer
uses pymodbus: it runs on the Modbus TCP engine, issue 29.)"""

from __future__ import annotations

import logging
import socket
import subprocess
import sys
from collections.abc import Iterator

import pytest

from starterbus.cli.logs import LIBRARY_LOGGERS, SILENT, configure_logging


def simulate_on_a_taken_port(*options: str) -> subprocess.CompletedProcess[str]:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        return subprocess.run(
            [sys.executable, "-m", "starterbus.cli.main", *options, "simulate", "--model", "jjr8000",
             "--profibus-gateway", f"127.0.0.1:{port}", "--ppo", "1"],
            capture_output=True, text=True, timeout=60, check=False,
        )  # fmt: skip


ERROR = "starterbus: error: profibus-pkw gateway simulator could not listen on 127.0.0.1:"


def test_a_pymodbus_error_shows_only_starterbus_one_line() -> None:
    done = simulate_on_a_taken_port()
    assert done.returncode == 1 and done.stdout == ""
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(ERROR), done.stderr
    assert "pymodbus" not in done.stderr


def test_verbose_shows_the_library_log_before_the_error() -> None:
    done = simulate_on_a_taken_port("-v")
    assert done.returncode == 1
    lines = done.stderr.splitlines()
    assert any(line.startswith("pymodbus") and "address already in use" in line for line in lines), done.stderr
    assert lines[-1].startswith(ERROR)


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
