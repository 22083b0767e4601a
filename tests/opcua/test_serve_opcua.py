"""``starterbus serve --demo --opcua URL``: the Sparkplug edge node and the OPC UA server on one fleet."""

from __future__ import annotations

import asyncio
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
from asyncua import Client
from asyncua.ua.uaerrors import BadWaitingForInitialData

EXE = shutil.which("starterbus") or str(Path(sys.executable).with_name("starterbus"))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.skipif(shutil.which("mosquitto") is None, reason="needs the mosquitto broker (CI installs it)")
def test_serve_demo_with_opcua(tmp_path: Path) -> None:
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    env = {**os.environ, "STARTERBUS_AUDIT_LOG": str(tmp_path / "audit.jsonl")}
    proc = subprocess.Popen(
        [EXE, "serve", "--demo", "--opcua", url, "--opcua-anonymous", "--opcua-allow-insecure",
         "--opcua-pki", str(tmp_path / "pki"), "--state-file", str(tmp_path / "bdseq"), "--duration", "60",
         "--record", str(tmp_path / "h.db")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip

    async def read_state() -> object:
        deadline = time.monotonic() + 30
        while True:  # wait on the observable: the server answers
            try:
                async with Client(url, timeout=2) as client:
                    ns = await client.get_namespace_index("urn:starterbus:fleet")
                    node = client.get_node(f"ns={ns};s=conveyor.Status.State")
                    while True:
                        try:
                            state = await node.read_value()
                        except BadWaitingForInitialData:  # before the first poll: wait for it
                            if time.monotonic() > deadline:
                                raise
                            await asyncio.sleep(0.1)
                            continue
                        # --record's history is HistoryRead's: the polls so far, Good, with their times
                        start = datetime.now(timezone.utc) - timedelta(minutes=5)
                        while not (history := await node.read_raw_history(start, datetime.now(timezone.utc))):
                            assert time.monotonic() < deadline
                            await asyncio.sleep(0.1)
                        assert all(dv.StatusCode.is_good() and dv.SourceTimestamp >= start for dv in history)
                        return state
            except (OSError, asyncio.TimeoutError):
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise
                await asyncio.sleep(0.2)

    try:
        assert isinstance(asyncio.run(read_state()), int)
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
    assert "OPC UA: " + url in out and "spBv1.0/starterbus" in out, err
