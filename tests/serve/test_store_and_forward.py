"""Store-and-forward survives a restart: mosquitto is stopped while serve runs, serve is killed (-9) and started
again before the broker returns; every DDATA buffered during the outage, by either process, arrives once, in
order, flagged historical, after the births of the new session (decoded with Tahu's schema)."""

from __future__ import annotations

import threading
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from prometheus_client.parser import text_string_to_metric_families

from starterbus.serve.embedded import Mosquitto, free_port, start_mosquitto
from starterbus.testing import wait_until

if TYPE_CHECKING:
    from starterbus.tests.serve.conftest import Host, Line, Message, Proxy, Serve

WAIT = 15.0


def is_(kind: str, device: str | None = None) -> Callable[[Message], bool]:
    return lambda m: m.kind == kind and (device is None or m.device == device)


def historical(m: Message) -> bool:
    return m.kind == "DDATA" and all(x.is_historical for x in m.payload.metrics)


def scrape(port: int) -> dict[str, float]:
    text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode()
    return {s.name: s.value for f in text_string_to_metric_families(text) for s in f.samples if not s.labels}


def reported(port: int, pred: Callable[[dict[str, float]], bool]) -> Callable[[], bool]:
    """A predicate for ``wait_until``: serve's own metrics satisfy ``pred`` (false while the endpoint is not up)."""

    def holds() -> bool:
        try:
            return pred(scrape(port))
        except OSError:
            return False

    return holds


def test_buffer_survives_kill_and_is_delivered_once_in_order(
    broker: Mosquitto,
    proxy: Proxy,
    line: Line,
    fleet_toml: Path,
    tmp_path: Path,
    host_factory: Callable[..., Host],
    serve: Callable[..., Serve],
) -> None:
    host = host_factory(broker.port)
    host.client.reconnect_delay_set(0.05, 0.2)  # type: ignore[arg-type]  # (paho hints int; it takes seconds as float)
    resubscribed = threading.Event()
    host.client.on_subscribe = lambda *_: resubscribed.set()
    common = [
        str(fleet_toml), "--mqtt", f"mqtt://127.0.0.1:{proxy.port}", "--group", "g1", "--node", "n1",
        "--state-file", str(tmp_path / "state.json"), "--reconnect-delay", "0.2",
    ]  # fmt: skip
    ports = free_port(), free_port()
    first = serve(*common, "--metrics", f"127.0.0.1:{ports[0]}")
    i, _ = host.wait(is_("NBIRTH"))
    host.wait(is_("DBIRTH", "pump"), after=i)
    # what was polled before this first connection goes out after the births; the broker is stopped only once
    # the host has it all (QoS 0 DDATA on its way through a broker that dies is lost: docs/serve.md, "Once")
    assert wait_until(reported(ports[0], lambda m: m["starterbus_serve_buffered"] == 0), WAIT)
    delivered = scrape(ports[0])["starterbus_serve_history_delivered_total"]
    assert wait_until(lambda: len([m for m in host.messages if historical(m)]) >= delivered, WAIT)

    broker.process.terminate()  # the broker goes away while serve runs
    broker.process.wait(10)
    assert wait_until(reported(ports[0], lambda m: m["starterbus_serve_connected"] == 0), WAIT), (
        "serve never reported the connection lost"
    )
    stored = scrape(ports[0])["starterbus_serve_history_stored_total"]
    line.starters[2].start()  # sampled during the outage: buffered on disk
    assert wait_until(reported(ports[0], lambda m: m["starterbus_serve_history_stored_total"] >= stored + 2), WAIT), (
        "serve never reported buffered DDATA"
    )
    first.kill()  # SIGKILL: no clean stop, nothing flushed by an exit handler
    killed_at = int(time.time() * 1000)
    proxy.cut()  # the restarted serve cannot reach the broker either

    second = serve(*common, "--metrics", f"127.0.0.1:{ports[1]}")
    assert wait_until(reported(ports[1], lambda m: m["starterbus_serve_buffered"] > 0), WAIT), (
        "serve never reported the buffer of the killed process"
    )
    stored = scrape(ports[1])["starterbus_serve_history_stored_total"]
    line.starters[2].soft_stop()  # sampled by the new process, still during the outage
    assert wait_until(reported(ports[1], lambda m: m["starterbus_serve_history_stored_total"] >= stored + 2), WAIT), (
        "serve never reported more buffered DDATA"
    )

    resubscribed.clear()
    again = start_mosquitto(broker.port)  # the broker returns on its port; the host reconnects first
    try:
        assert resubscribed.wait(15), "the host application did not reconnect"
        mark = len(host.messages)
        proxy.resume()
        k, _ = host.wait(is_("NBIRTH"), after=mark)
        d, _ = host.wait(is_("DBIRTH", "pump"), after=k)
        assert wait_until(reported(ports[1], lambda m: m["starterbus_serve_buffered"] == 0), WAIT), (
            "serve never reported an empty buffer"
        )
        totals = scrape(ports[1])
        stored = totals["starterbus_serve_history_stored_total"]
        # "delivered" is written to serve's socket; the last batch may still be on its way to the host
        assert wait_until(lambda: len([m for m in host.messages if historical(m)]) >= stored, WAIT), (
            "the host did not receive every buffered message"
        )
        history = [m for m in host.messages if historical(m)]
        assert second.process.poll() is None
    finally:
        again.close()

    # every buffered DDATA arrived once (none dropped, none twice), after the births of the new session
    assert totals["starterbus_serve_dropped_total"] == 0
    assert totals["starterbus_serve_history_delivered_total"] == totals["starterbus_serve_history_stored_total"]
    outage = [m for m in history if host.messages.index(m) > k]
    assert outage and all(host.messages.index(m) > d for m in outage)
    before = [m for m in history if host.messages.index(m) < mark]  # polled before the very first connection
    assert len(before) + len(outage) == totals["starterbus_serve_history_stored_total"]
    names = host.aliases["pump"]
    stamps = [tuple((x.alias, x.timestamp) for x in m.payload.metrics) for m in outage]
    assert len(set(stamps)) == len(stamps)  # no duplicate
    times = [max(x.timestamp for x in m.payload.metrics) for m in outage]
    assert times == sorted(times)  # in the order sampled, across both processes
    states = [x.string_value for m in outage for x in m.payload.metrics if names.get(x.alias) == "Status/State"]
    by_first = [m for m in outage if max(x.timestamp for x in m.payload.metrics) < killed_at]
    assert any(names.get(x.alias) == "Status/State" for m in by_first for x in m.payload.metrics)
    first_start = states.index("starting")  # sampled by the first process, then the stop by the second
    assert any(s in ("stopping", "stopped", "ready") for s in states[first_start + 1 :]), states
