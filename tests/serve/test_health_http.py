"""``/healthz``, ``/readyz`` and the service series on the metrics port (issue 26, item 5): in-process with a
stalling poller, and ``serve`` as a subprocess with a real mosquitto that goes away."""

from __future__ import annotations

import json
import socket
import urllib.error
import urllib.request
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families

from starterbus.core.device import Device
from starterbus.core.registry import get_profile
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.health import PollHealth
from starterbus.fleet.poller import FleetPoller
from starterbus.serve.embedded import Mosquitto
from starterbus.serve.prometheus import FleetCollector, start_metrics_server
from starterbus.testing.conformance import wait_until
from starterbus.tests.fleet.test_health import FLEET, GatedTransport

from .conftest import WAIT, Serve

Fetch = Callable[[str], tuple[int, str]]


def fetch(url: str) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(url, timeout=5) as answer:
            return answer.status, answer.read().decode()
    except urllib.error.HTTPError as error:
        return error.code, error.read().decode()


def readyz(base: str) -> tuple[int, dict[str, object]]:
    code, body = fetch(base + "/readyz")
    return code, json.loads(body)


@pytest.fixture
def gated() -> Iterator[tuple[FleetPoller, dict[str, GatedTransport]]]:
    poller = FleetPoller(parse_fleet(FLEET), multiplex=False)
    profile = get_profile("jjr5000")
    gates = {}
    for worker in poller.workers:
        gates[worker.bus.name] = GatedTransport(profile)
        worker.devices[0].device = Device(gates[worker.bus.name], profile).open()
    try:
        yield poller, gates
    finally:
        for gate in gates.values():
            gate.gate.set()
        poller.stop()


def test_readyz_follows_the_polls_and_healthz_answers(gated: tuple[FleetPoller, dict[str, GatedTransport]]) -> None:
    poller, gates = gated
    health = PollHealth(poller, stall_after=0.5)
    collector = FleetCollector()
    collector.poller = poller
    host, port, server = start_metrics_server("127.0.0.1:0", collector, health=health)
    base = f"http://{host}:{port}"
    try:
        code, body = readyz(base)
        assert code == 503 and body["ready"] is False and "first poll" in str(body["reason"]), "nothing polled yet"
        poller.start()
        assert wait_until(lambda: readyz(base)[0] == 200, WAIT)
        assert readyz(base)[1]["reason"] == "polling"

        gates["b"].gate.clear()  # bus b hangs in its next poll
        assert gates["b"].blocked.wait(WAIT)
        assert wait_until(lambda: readyz(base)[0] == 503, WAIT)
        _, body = readyz(base)
        assert body["stalled"] == ["b"] and "stalled" in str(body["reason"]) and "bus b" in str(body["reason"])
        assert fetch(base + "/healthz") == (200, '{"alive": true}\n'), "alive while not ready"

        gates["b"].gate.set()
        assert wait_until(lambda: readyz(base)[0] == 200, WAIT)

        code, text = fetch(base + "/metrics")
        assert code == 200
        families = {f.name: f for f in text_string_to_metric_families(text)}
        [build] = families["starterbus_build_info"].samples  # an info metric, as the text format says it
        assert build.value == 1 and set(build.labels) == {"version", "python"}
        ages = {s.labels["device"]: s.value for s in families["starterbus_device_last_good_poll_age_seconds"].samples}
        assert set(ages) == {"da", "db"} and all(0 <= a < WAIT for a in ages.values())
        assert "process_cpu_seconds" in families and "python_info" in families, "process and platform collectors"
        assert {s.labels["device"] for s in families["starterbus_device_online"].samples} == {"da", "db"}
    finally:
        server.close()


def test_serve_is_ready_while_connected_and_tells_systemd(
    broker: Mosquitto, fleet_toml: Path, serve: Callable[..., Serve], tmp_path: Path
) -> None:
    address = f"@starterbus-test-{uuid.uuid4().hex}"
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind("\0" + address[1:])
    notify.settimeout(WAIT)
    s = serve(
        str(fleet_toml), "--mqtt", broker.url, "--group", "g1", "--node", "n1", "--metrics", "127.0.0.1:0", "--json",
        "--state-file", str(tmp_path / "state.json"),
        env={"NOTIFY_SOCKET": address, "WATCHDOG_USEC": "500000"},
    )  # fmt: skip
    try:
        lines: list[str] = []
        while "READY=1" not in lines:
            lines = notify.recv(4096).decode().split("\n")
        while "WATCHDOG=1" not in lines:
            lines = notify.recv(4096).decode().split("\n")
        assert wait_until(lambda: '"metrics"' in s.output(), WAIT), s.output()
        ready = json.loads(next(x for x in s.output().splitlines() if x.startswith("{")))
        base = str(ready["metrics"]).removesuffix("/metrics")
        assert wait_until(lambda: readyz(base)[0] == 200, WAIT), (readyz(base), s.output())

        broker.close()  # the broker goes away: not ready (polling goes on), still alive
        assert wait_until(lambda: readyz(base)[0] == 503, WAIT), s.output()
        _, body = readyz(base)
        assert "broker" in str(body["reason"]) and body["progressing"] is True, body
        assert fetch(base + "/healthz")[0] == 200
    finally:
        s.process.terminate()
        s.process.wait(WAIT)
        while "STOPPING=1" not in lines:
            lines = notify.recv(4096).decode().split("\n")
        notify.close()
    assert s.process.returncode == 0, s.output()
