"""Broker unreachable: polling goes on, DDATA is buffered; on reconnect a new NBIRTH (new bdSeq), the DBIRTHs,
then the buffered data as historical DDATA, in order. The host application stays connected to the broker
directly; only serve's path to it is cut (a TCP proxy), so every message is observed."""

from __future__ import annotations

import threading
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from prometheus_client.parser import text_string_to_metric_families

from starterbus.serve.embedded import Mosquitto, free_port

if TYPE_CHECKING:
    from starterbus.tests.serve.conftest import Host, Line, Message, Proxy, Serve


def is_(kind: str, device: str | None = None) -> Callable[[Message], bool]:
    return lambda m: m.kind == kind and (device is None or m.device == device)


def bdseq(m: Message) -> int:
    return int(next(x.long_value for x in m.payload.metrics if x.name == "bdSeq"))


def buffered(port: int) -> float:
    text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode()
    families = {f.name: f for f in text_string_to_metric_families(text)}
    return float(families["starterbus_serve_buffered"].samples[0].value)


def test_buffered_while_unreachable_then_rebirth_and_history(
    broker: Mosquitto,
    proxy: Proxy,
    line: Line,
    fleet_toml: Path,
    tmp_path: Path,
    host_factory: Callable[..., Host],
    serve: Callable[..., Serve],
) -> None:
    host = host_factory(broker.port)
    metrics_port = free_port()
    serve(
        str(fleet_toml), "--mqtt", f"mqtt://127.0.0.1:{proxy.port}", "--group", "g1", "--node", "n1",
        "--state-file", str(tmp_path / "state.json"), "--metrics", f"127.0.0.1:{metrics_port}",
        "--reconnect-delay", "0.2",
    )  # fmt: skip
    i, first = host.wait(is_("NBIRTH"))
    host.wait(is_("DBIRTH", "pump"), after=i)

    proxy.cut()
    j, will = host.wait(is_("NDEATH"), after=i)  # the broker saw serve go: its Will
    assert bdseq(will) == bdseq(first)
    line.starters[2].start()  # the motor starts while the broker is unreachable
    pause = threading.Event()
    deadline = time.monotonic() + 15
    while buffered(metrics_port) == 0:  # wait on the observable: serve's own count of buffered messages
        assert time.monotonic() < deadline, "nothing was buffered while the broker was unreachable"
        pause.wait(0.05)

    proxy.resume()
    k, second = host.wait(is_("NBIRTH"), after=j)
    assert bdseq(second) > bdseq(first) and second.payload.seq == 0
    d, _ = host.wait(is_("DBIRTH", "pump"), after=k)
    _, history = host.wait(lambda m: is_("DDATA", "pump")(m) and m.payload.metrics[0].is_historical, after=k)
    assert host.messages.index(history) > d  # births first, then the history
    states = [
        v
        for m in host.messages[k:]
        if is_("DDATA", "pump")(m)
        for n, v in host.values(m).items()
        if n == "Status/State"
    ]
    assert "starting" in states or "running" in states
    between = [m for m in host.messages[j:k] if m.kind in ("DDATA", "NDATA", "DBIRTH")]
    assert between == []  # nothing published while cut
