"""``--metrics HOST:PORT``: the fleet and the edge node for Prometheus (prometheus-client, collected at scrape),
and the supervisor's probes ``/healthz`` and ``/readyz`` on the same port.

Per device: online, state (one series per state, 1 for the current one), fault code, every polled value and the
age of its last good poll. Polled values go to one family per unit, in Prometheus's base units
(:data:`UNIT_FAMILIES`: ``starterbus_device_value_amperes``, ``..._percent``, ``..._seconds`` with minutes and
hours converted, ...; ``starterbus_device_value`` for values without a unit), so no family mixes units. Per line:
transactions and offline devices from the poller; requests, retries, timeouts, errors and
``starterbus_line_utilisation_ratio`` when the poller counts them (``FleetPoller.line_stats()``: each line's
``wire`` counters and ``utilisation``; else same-named attributes of the bus workers). A poller without them:
those series are absent. Also ``starterbus_build_info`` and the client library's process and platform collectors.
"""

from __future__ import annotations

import json
import math
import platform
import re
import socket
import threading
from collections.abc import Callable, Iterable, Iterator
from socketserver import ThreadingMixIn
from typing import TYPE_CHECKING, Any
from wsgiref.simple_server import WSGIRequestHandler, WSGIServer, make_server

from prometheus_client import CollectorRegistry, PlatformCollector, ProcessCollector, make_wsgi_app
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, InfoMetricFamily, Metric
from prometheus_client.registry import Collector

import starterbus
from starterbus.core.status import MotorState
from starterbus.core.textinput import listen_error, parse_host_port
from starterbus.fleet.health import PollHealth
from starterbus.fleet.poller import FleetPoller, Sample

if TYPE_CHECKING:
    from starterbus.serve.session import EdgeSession

_LINE_COUNTERS = (
    ("requests", "requests sent, retries included"),
    ("retries", "requests retried"),
    ("timeouts", "transactions without an answer"),
    ("errors", "transactions that failed"),
)


#: a profile's unit -> the suffix of its family and the factor to that base unit (Prometheus: base units, and
#: one unit per family); another unit gets a family of its own, named after it (``kW`` -> ``_kw``)
UNIT_FAMILIES: dict[str, tuple[str, float]] = {
    "": ("", 1.0),  # codes (enums), counts, settings without a unit
    "A": ("amperes", 1.0),
    "%": ("percent", 1.0),  # as the device shows it: 350 is 350 % (of the rated current, of the thermal capacity)
    "x In": ("ratio", 1.0),  # a multiple of the motor's rated current In: 3.5 is 3.5 x In
    "s": ("seconds", 1.0),
    "min": ("seconds", 60.0),
    "h": ("seconds", 3600.0),
    "°C": ("celsius", 1.0),
    "cycles": ("cycles", 1.0),
}


def value_family(unit: str) -> tuple[str, float]:
    """The family name of a polled value in ``unit`` and the factor that converts it to the family's unit."""
    known = UNIT_FAMILIES.get(unit)
    if known is None:
        suffix = re.sub(r"[^a-z0-9]+", "_", unit.casefold()).strip("_") or "unit_" + unit.encode().hex()
        known = (suffix, 1.0)
    suffix, factor = known
    return ("starterbus_device_value_" + suffix if suffix else "starterbus_device_value"), factor


def _value_help(name: str, unit: str) -> str:
    if name == "starterbus_device_value":
        return "polled values without a unit (enum codes, counts), by point key"
    units = sorted(u for u in UNIT_FAMILIES if value_family(u)[0] == name) or [unit]
    base = name.removeprefix("starterbus_device_value_")
    return f"polled values in {base} (the profile's {', '.join(repr(u) for u in units)}), by point key"


class FleetCollector(Collector):
    def __init__(self, session: EdgeSession | None = None) -> None:
        self.poller: FleetPoller | None = None
        self.session = session
        self._latest: dict[str, Sample] = {}
        self._lock = threading.Lock()

    def observe(self, sample: Sample) -> None:
        with self._lock:
            self._latest[sample.device] = sample

    def _samples(self) -> list[Sample]:
        """The latest sample of each device: the poller's own (``poll``, ``opcua``), else those observed."""
        runtimes = getattr(self.poller, "runtimes", None)
        if callable(runtimes):
            return [r.last_sample for r in runtimes() if r.last_sample is not None]
        with self._lock:
            return list(self._latest.values())

    def collect(self) -> Iterator[Metric]:
        samples = self._samples()
        online = GaugeMetricFamily(
            "starterbus_device_online", "1 if the device answered its last poll", labels=["device", "line", "model"]
        )
        state = GaugeMetricFamily(
            "starterbus_device_state", "1 for the device's current motor state", labels=["device", "state"]
        )
        fault = GaugeMetricFamily("starterbus_device_fault_code", "fault code (0: no fault)", labels=["device"])
        values: dict[str, GaugeMetricFamily] = {}
        for s in samples:
            online.add_metric([s.device, s.bus, s.model], 1.0 if s.online else 0.0)
            if s.online and s.status is not None:
                current = s.status.state
                for st in MotorState:
                    state.add_metric([s.device, st.value], 1.0 if st is current else 0.0)
                fault.add_metric([s.device], float(s.status.fault_code or 0))
            for key, v in s.values.items():
                name, factor = value_family(v.unit)
                family = values.get(name)
                if family is None:
                    family = values[name] = GaugeMetricFamily(name, _value_help(name, v.unit), labels=["device", "key"])
                family.add_metric([s.device, key], float(v.value) * factor)
        yield from (online, state, fault)
        yield from (values[name] for name in sorted(values))
        yield from self._ages()
        yield from self._lines(samples)
        yield from self._node()
        yield InfoMetricFamily(
            "starterbus_build", "starterbus version", value={"version": starterbus.__version__, "python": _PYTHON}
        )

    def _ages(self) -> Iterator[Metric]:
        poller = self.poller
        runtimes = getattr(poller, "runtimes", None)
        if poller is None or not callable(runtimes):
            return
        age = GaugeMetricFamily(
            "starterbus_device_last_good_poll_age_seconds",
            "seconds since the device last answered a poll (+Inf: not since the start)",
            labels=["device"],
        )
        now = poller.clock()
        for r in runtimes():
            age.add_metric([r.config.name], now - r.last_ok if r.last_ok is not None else math.inf)
        yield age

    def _lines(self, samples: list[Sample]) -> Iterator[Metric]:
        poller = self.poller
        if poller is None:
            return
        transactions = CounterMetricFamily("starterbus_line_transactions", "transactions on the line", labels=["line"])
        offline = GaugeMetricFamily("starterbus_line_offline_devices", "devices not answering", labels=["line"])
        util = GaugeMetricFamily(
            "starterbus_line_utilisation_ratio", "fraction of the time the line was busy (0..1)", labels=["line"]
        )
        counters = {n: CounterMetricFamily(f"starterbus_line_{n}", h, labels=["line"]) for n, h in _LINE_COUNTERS}
        line_stats = getattr(poller, "line_stats", None)
        stats = line_stats() if callable(line_stats) else {}
        for worker in poller.workers:
            line = worker.bus.name
            transactions.add_metric([line], float(worker.transactions))
            offline.add_metric([line], float(sum(1 for r in worker.devices if r.online is False)))
            line_stat = stats.get(line)
            wire = getattr(line_stat, "wire", worker)
            for name, family in counters.items():
                count = getattr(wire, name, None)
                if isinstance(count, (int, float)):
                    family.add_metric([line], float(count))
            busy = getattr(line_stat if line_stat is not None else worker, "utilisation", None)
            if callable(busy):
                busy = busy()
            if isinstance(busy, (int, float)):
                util.add_metric([line], float(busy))
        yield transactions
        yield offline
        yield from (f for f in counters.values() if f.samples)
        if util.samples:
            yield util

    def _node(self) -> Iterator[Metric]:
        session = self.session
        if session is None:
            return
        yield GaugeMetricFamily(
            "starterbus_serve_connected", "1 while the node is born on the broker", value=float(session.born)
        )
        yield GaugeMetricFamily(
            "starterbus_serve_bdseq", "bdSeq of the current MQTT session", value=float(session.bdseq)
        )
        store = session.store
        yield GaugeMetricFamily(
            "starterbus_serve_buffered", "DDATA messages waiting for the broker", value=float(len(store))
        )
        yield CounterMetricFamily(
            "starterbus_serve_history_stored", "DDATA messages buffered for the broker", value=float(store.buffered)
        )
        yield CounterMetricFamily(
            "starterbus_serve_history_delivered", "buffered DDATA written to a broker", value=float(store.delivered)
        )
        yield CounterMetricFamily(
            "starterbus_serve_dropped", "buffered DDATA dropped (a bound, or not storable)", value=float(store.dropped)
        )
        yield CounterMetricFamily(
            "starterbus_serve_commands_refused", "DCMDs refused or failed", value=float(session.refused)
        )
        yield CounterMetricFamily(
            "starterbus_serve_published", "Sparkplug messages published (with seq)", value=float(session.published)
        )


_PYTHON = platform.python_version()
Respond = Callable[[str, list[tuple[str, str]]], Any]
App = Callable[[dict[str, Any], Respond], Iterable[bytes]]


def health_app(metrics: App, health: PollHealth | None) -> App:
    """``/healthz`` (the process answers: 200), ``/readyz`` (200 while ready, else 503; a JSON body says why), and
    on every other path the metrics (prometheus-client's application)."""

    def app(environ: dict[str, Any], respond: Respond) -> Iterable[bytes]:
        path = environ.get("PATH_INFO", "")
        if path not in ("/healthz", "/readyz"):
            return metrics(environ, respond)
        body: dict[str, object] = {"alive": True}
        code = "200 OK"
        if path == "/readyz":
            body = health.check().as_json() if health is not None else {"ready": True, "reason": "polling"}
            code = "200 OK" if body["ready"] else "503 Service Unavailable"
        data = (json.dumps(body) + "\n").encode()
        respond(code, [("Content-Type", "application/json"), ("Content-Length", str(len(data)))])
        return [data]

    return app


class _QuietHandler(WSGIRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:
        pass


class MetricsServer:
    """The HTTP server of ``--metrics`` in a thread of its own (one more per request); :meth:`close` stops it."""

    def __init__(self, host: str, port: int, app: App) -> None:
        class Server(ThreadingMixIn, WSGIServer):
            daemon_threads = True
            address_family = socket.AF_INET6 if ":" in host else socket.AF_INET

        self.server = make_server(host, port, app, Server, _QuietHandler)
        self.port = int(self.server.server_address[1])
        self.thread = threading.Thread(target=self.server.serve_forever, name="metrics-http", daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def _health_of(collector: FleetCollector) -> PollHealth | None:
    poller, session = collector.poller, collector.session
    if not isinstance(poller, FleetPoller):
        return None
    if session is None:
        return PollHealth(poller)
    return PollHealth(poller, checks=[lambda: None if session.connected else "not connected to a broker"])


def start_metrics_server(
    address: str, collector: FleetCollector, *more: Collector, health: PollHealth | None = None
) -> tuple[str, int, MetricsServer]:
    """Serve ``/metrics``, ``/healthz`` and ``/readyz`` on ``HOST:PORT`` (port 0: any free port); returns the
    host, the port and the server. ``more``: other collectors served beside (the service's own health);
    ``health``: what ``/readyz`` reports (by default the collector's poller, and for ``serve`` its broker
    connection)."""
    host, port = parse_host_port(address, option="--metrics")
    health = health if health is not None else _health_of(collector)
    registry = CollectorRegistry(auto_describe=False)
    for each in (collector, *more):
        registry.register(each)
    ProcessCollector(registry=registry)
    PlatformCollector(registry=registry)
    try:
        server = MetricsServer(host, port, health_app(make_wsgi_app(registry), health))
    except OSError as exc:
        raise listen_error("--metrics", host, port, exc) from None
    return host, server.port, server
