"""``serve --demo`` with no broker named: the embedded mosquitto, the watch command it prints, every demo
device born, and on SIGTERM a clean stop (NDEATH published by serve itself, then DISCONNECT)."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from starterbus.serve.embedded import mosquitto_binary

if TYPE_CHECKING:
    from starterbus.tests.serve.conftest import Host

DEMO_DEVICES = {"conveyor", "fan", "crusher", "mill", "mixer", "pump-a", "pump-b"}


@pytest.fixture
def demo_serve(tmp_path: Path) -> Iterator[subprocess.Popen[str]]:
    if mosquitto_binary() is None:
        pytest.skip("mosquitto is not installed (apt-get install mosquitto)")
    cmd = [sys.executable, "-m", "starterbus.cli.main", "serve", "--demo", "--node", "demo"]
    process = subprocess.Popen(
        [*cmd, "--state-file", str(tmp_path / "s.json")], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        yield process
    finally:
        if process.poll() is None:
            process.kill()
        process.wait(10)


def test_demo_with_embedded_broker(demo_serve: subprocess.Popen[str], host_factory: Callable[..., Host]) -> None:
    assert demo_serve.stdout is not None
    lines: list[str] = []
    found = threading.Event()

    def read() -> None:
        assert demo_serve.stdout is not None
        for text in demo_serve.stdout:
            lines.append(text)
            if "mosquitto_sub" in text:
                found.set()

    threading.Thread(target=read, daemon=True).start()
    assert found.wait(30), "".join(lines)
    assert any("not for production" in x for x in lines)
    match = re.search(r"mosquitto_sub -h 127\.0\.0\.1 -p (\d+) -t 'spBv1\.0/#' -v", "".join(lines))
    assert match is not None
    host = host_factory(int(match.group(1)))
    host.group, host.node = "starterbus", "demo"
    host.send("NCMD", None, [("Node Control/Rebirth", 11, "boolean_value", True)])  # births we may have missed
    seen: set[str] = set()
    deadline = time.monotonic() + 20
    while seen != DEMO_DEVICES:
        _, m = host.wait(
            lambda m: m.kind == "DBIRTH" and m.device not in seen, timeout=max(0.1, deadline - time.monotonic())
        )
        seen.add(m.device or "")
    demo_serve.send_signal(signal.SIGTERM)
    _, death = host.wait(lambda m: m.kind == "NDEATH")
    assert death.topic == "spBv1.0/starterbus/NDEATH/demo"
    assert demo_serve.wait(15) == 0
