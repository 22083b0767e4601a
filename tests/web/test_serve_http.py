"""``starterbus serve FLEET --http HOST:PORT`` (or ``--opcua URL``) with no ``--mqtt``: no broker started or needed.

The simulated starters run in this process (the demo's simulators: serial lines on PTYs and PROFIBUS gateways on
TCP); ``serve`` runs as a subprocess with a fleet file that reaches them.
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from starterbus.cli.main import main
from starterbus.fleet.demo import DemoFleet, start_demo_fleet
from starterbus.testing import wait_until, wait_until_async


@pytest.fixture(scope="module")
def demo() -> Iterator[DemoFleet]:
    running = start_demo_fleet(0.5)
    try:
        yield running
    finally:
        running.close()


def _fleet_file(demo: DemoFleet, path: Path) -> list[str]:
    """The demo's lines a subprocess can reach (its DeviceNet bus is a virtual CAN channel of this process)."""
    lines = ["[poll]", "period = 0.5", ""]
    names = []
    for bus in demo.config.buses:
        if bus.transport == "devicenet":
            continue
        lines += ["[[bus]]", f'name = "{bus.name}"', f'url = "{bus.url}"', ""]
        for d in bus.devices:
            lines += ["  [[bus.device]]", f'  name = "{d.name}"', f'  model = "{d.model}"', f"  address = {d.address}"]
            names.append(d.name)
    path.write_text("\n".join(lines) + "\n")
    return names


def _get(url: str) -> Any:
    with urllib.request.urlopen(url, timeout=10) as r:
        return json.loads(r.read())


def test_serve_fleet_http_without_mqtt_serves_the_fleet_page(demo: DemoFleet, tmp_path: Path) -> None:
    fleet = tmp_path / "fleet.toml"
    names = _fleet_file(demo, fleet)
    env = {**os.environ, "XDG_STATE_HOME": str(tmp_path), "STARTERBUS_AUDIT_LOG": str(tmp_path / "audit.jsonl")}
    command = [sys.executable, "-m", "starterbus.cli.main", "serve", str(fleet), "--http", "127.0.0.1:0",
               "--record", str(tmp_path / "history.db"), "--json", "--duration", "60"]  # fmt: skip
    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env) as proc:
        try:
            assert proc.stdout is not None
            line = proc.stdout.readline()
            assert line, proc.stderr.read() if proc.stderr else ""
            ready = json.loads(line)
            assert ready["broker"] is None and ready["brokers"] == [] and ready["embedded_broker"] is False
            assert ready["http"].startswith("http://127.0.0.1:") and ready["opcua"] is None
            with urllib.request.urlopen(ready["http"], timeout=10) as page:
                assert b"fleet.js" in page.read()
            api = ready["http"] + "api/"

            def all_online() -> bool:
                rows = _get(api + "fleet")["devices"]
                return sorted(d["name"] for d in rows) == sorted(names) and all(d["online"] for d in rows)

            assert wait_until(all_online, 30)  # polled, with no broker anywhere
            assert wait_until(lambda: len(_get(api + f"devices/{names[0]}/history?key=current_a")["t"]) > 1, 30)
            assert not (tmp_path / "starterbus").exists()  # no edge node: no bdSeq state, no store-and-forward buffer
        finally:
            proc.terminate()
            proc.wait(30)
    assert proc.returncode == 0


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ([], "give --mqtt URL, --opcua URL or --http HOST:PORT"),
        (["--http", "127.0.0.1:0", "--primary-host", "scada"], "--primary-host needs --mqtt URL"),
    ],
)
def test_serve_without_mqtt_needs_a_listener_and_no_mqtt_options(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    fleet = tmp_path / "fleet.toml"
    fleet.write_text('[[bus]]\nname = "l"\nurl = "modbus-rtu:///dev/null"\n')
    assert main(["serve", str(fleet), *extra]) == 1
    assert message in capsys.readouterr().err


def test_serve_fleet_opcua_alone_serves_the_fleet_over_opc_ua(demo: DemoFleet, tmp_path: Path) -> None:
    asyncua = pytest.importorskip("asyncua", reason="asyncua is not installed (pip install .[opcua])")
    fleet = tmp_path / "fleet.toml"
    names = _fleet_file(demo, fleet)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        url = f"opc.tcp://127.0.0.1:{s.getsockname()[1]}"
    env = {**os.environ, "XDG_STATE_HOME": str(tmp_path), "STARTERBUS_AUDIT_LOG": str(tmp_path / "audit.jsonl")}
    command = [sys.executable, "-m", "starterbus.cli.main", "serve", str(fleet), "--opcua", url, "--opcua-anonymous",
               "--opcua-allow-insecure", "--opcua-pki", str(tmp_path / "pki"), "--json"]  # fmt: skip

    async def read_state() -> object:
        async with asyncua.Client(url, timeout=5) as client:
            ns = await client.get_namespace_index("urn:starterbus:fleet")
            node = client.get_node(f"ns={ns};s={names[0]}.Status.State")
            assert await wait_until_async(lambda: _readable(node), 30)
            return await node.read_value()

    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env) as proc:
        try:
            assert proc.stdout is not None
            line = proc.stdout.readline()
            assert line, proc.stderr.read() if proc.stderr else ""
            ready = json.loads(line)
            assert ready["broker"] is None and ready["http"] is None and ready["opcua"].startswith("opc.tcp://")
            assert isinstance(asyncio.run(read_state()), int)  # polled and served, with no broker anywhere
        finally:
            proc.terminate()
            proc.wait(30)
    assert proc.returncode == 0 and not (tmp_path / "starterbus").exists()


async def _readable(node: Any) -> bool:
    """Whether the node has its first value (before the first poll it answers BadWaitingForInitialData)."""
    from asyncua.ua.uaerrors import UaStatusCodeError

    try:
        await node.read_value()
    except UaStatusCodeError:
        return False
    return True
