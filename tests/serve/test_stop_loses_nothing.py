"""A requested stop loses no sample: polling ends first, and what it polled last is published before the NDEATH,
so every sample of the history (`serve --record`) reached the Sparkplug host (matched by acquisition time)."""

from __future__ import annotations

import asyncio
import sqlite3
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from prometheus_client.parser import text_string_to_metric_families

from starterbus.aio import AsyncFleet
from starterbus.fleet.config import load_fleet
from starterbus.fleet.poller import FleetPoller
from starterbus.fleet.sample import Sample
from starterbus.serve.actions import SessionOptions
from starterbus.serve.broker import BrokerOptions
from starterbus.serve.driver import EdgeNodeDriver
from starterbus.serve.embedded import Mosquitto, free_port
from starterbus.serve.session import EdgeSession
from starterbus.testing import wait_until

if TYPE_CHECKING:  # conftest is not importable at run time (pytest's importlib mode)
    from starterbus.tests.serve.conftest import Host, Line, Message, Serve


def buffered(port: int) -> float | None:
    """serve's own count of DDATA waiting in its store (None while the endpoint is not up)."""
    try:
        text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode()
    except OSError:
        return None
    values = {s.name: s.value for f in text_string_to_metric_families(text) for s in f.samples if not s.labels}
    return values.get("starterbus_serve_buffered")


def test_a_requested_stop_publishes_every_sample_it_polled(
    broker: Mosquitto,
    line: Line,
    fleet_toml: Path,
    tmp_path: Path,
    host_factory: Callable[..., Host],
    serve: Callable[..., Serve],
) -> None:
    host = host_factory(broker.port)
    db = tmp_path / "history.db"
    port = free_port()
    node = serve(
        str(fleet_toml), "--mqtt", broker.url, "--group", "g1", "--node", "n1", "--refresh", "0.001",
        "--state-file", str(tmp_path / "state.json"), "--record", str(db), "--metrics", f"127.0.0.1:{port}",
    )  # fmt: skip
    host.wait(lambda m: m.kind == "DBIRTH" and m.device == "fan")
    assert wait_until(lambda: buffered(port) == 0, 15.0), "what was polled before the births was never sent"
    line.starters[2].start()  # values change while it stops
    host.wait(lambda m: m.kind == "DDATA" and m.device == "pump" and host.values(m).get("Status/State") == "starting")
    assert wait_until(lambda: sum(m.kind == "DDATA" for m in host.messages) >= 20, 15.0), "no live data"
    node.process.terminate()
    assert node.process.wait(15) == 0, node.output()
    host.wait(lambda m: m.kind == "NDEATH")

    def stamps(m: Message) -> set[int]:
        return {x.timestamp for x in m.payload.metrics} if m.kind in ("DBIRTH", "DDATA") else set()

    received = {d: set().union(*(stamps(m) for m in host.messages if m.device == d)) for d in ("pump", "fan")}
    with sqlite3.connect(db) as conn:
        rows = conn.execute("SELECT device, time FROM samples WHERE online = 1").fetchall()
    assert len(rows) > 10
    missing = sorted((d, int(t * 1000)) for d, t in rows if int(t * 1000) not in received[d])
    assert not missing, f"{len(missing)} of {len(rows)} samples polled and recorded never reached the host: {missing}"


def test_the_edge_node_stops_polling_before_it_says_goodbye(
    broker: Mosquitto, line: Line, fleet_toml: Path, host_factory: Callable[..., Host]
) -> None:
    """The same, in one process and without luck: when ``run`` returns, the poller has stopped (no sample can
    follow the NDEATH), and every sample the poller handed over (seen by the fleet's sink, in the bus threads)
    reached the host."""
    host = host_factory(broker.port)
    config = load_fleet(fleet_toml)
    polled: list[Sample] = []

    async def run() -> FleetPoller | None:
        async with AsyncFleet(config, sink=polled.append) as fleet:
            session = EdgeSession.for_fleet(config, SessionOptions("g1", "n1", refresh=0.001))
            driver = EdgeNodeDriver(fleet, session, BrokerOptions("127.0.0.1", broker.port, client_id="edge"))
            stop = asyncio.Event()
            running = asyncio.create_task(driver.run(stop))
            births = asyncio.to_thread(host.wait, lambda m: m.kind == "DBIRTH" and m.device == "fan")
            await births
            enough = asyncio.to_thread(wait_until, lambda: sum(m.kind == "DDATA" for m in host.messages) >= 10, 15.0)
            assert await enough
            stop.set()
            await running
            assert fleet.poller is not None and fleet.poller.stopping.is_set(), "still polling after the goodbye"
            return fleet.poller

    asyncio.run(run())
    host.wait(lambda m: m.kind == "NDEATH")
    received = {
        (m.device, x.timestamp) for m in host.messages if m.kind in ("DBIRTH", "DDATA") for x in m.payload.metrics
    }
    missing = [(s.device, int(s.time * 1000)) for s in polled if (s.device, int(s.time * 1000)) not in received]
    assert not missing, f"{len(missing)} of {len(polled)} samples polled never reached the host: {missing}"
