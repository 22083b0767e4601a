"""``--metrics HOST:PORT``: the fleet and the edge node for Prometheus (prometheus-client, collected at scrape).

Per device: online, state (one series per state, 1 for the current one), fault code and every polled value.
Per line: transactions and offline devices from the poller; requests, retries, timeouts, errors and
utilisation when the poller counts them (``FleetPoller.line_stats()``: each line's ``wire`` counters and
``utilisation``; else same-named attributes of the bus workers). A poller without them: those series are absent.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import TYPE_CHECKING

from prometheus_client import CollectorRegistry, start_http_server
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from starterbus.core.status import MotorState
from starterbus.core.textinput import listen_error, parse_host_port
from starterbus.fleet.poller import FleetPoller, Sample

if TYPE_CHECKING:
    from starterbus.serve.session import EdgeSession

_LINE_COUNTERS = (
    ("requests", "requests sent, retries included"),
    ("retries", "requests retried"),
    ("timeouts", "transactions without an answer"),
    ("errors", "transactions that failed"),
)


class FleetCollector(Collector):
    def __init__(self, session: EdgeSession | None = None) -> None:
        self.poller: FleetPoller | None = None
        self.session = session
        self._latest: dict[str, Sample] = {}
        self._lock = threading.Lock()

    def observe(self, sample: Sample) -> None:
        with self._lock:
            self._latest[sample.device] = sample

    def collect(self) -> Iterator[Metric]:
        with self._lock:
            samples = list(self._latest.values())
        online = GaugeMetricFamily(
            "starterbus_device_online", "1 if the device answered its last poll", labels=["device", "line", "model"]
        )
        state = GaugeMetricFamily(
            "starterbus_device_state", "1 for the device's current motor state", labels=["device", "state"]
        )
        fault = GaugeMetricFamily("starterbus_device_fault_code", "fault code (0: no fault)", labels=["device"])
        value = GaugeMetricFamily(
            "starterbus_device_value", "polled value in engineering units", labels=["device", "key", "unit"]
        )
        for s in samples:
            online.add_metric([s.device, s.bus, s.model], 1.0 if s.online else 0.0)
            if s.online and s.status is not None:
                current = s.status.state
                for st in MotorState:
                    state.add_metric([s.device, st.value], 1.0 if st is current else 0.0)
                fault.add_metric([s.device], float(s.status.fault_code or 0))
            for key, v in s.values.items():
                value.add_metric([s.device, key, v.unit], float(v.value))
        yield from (online, state, fault, value)
        yield from self._lines(samples)
        yield from self._node()

    def _lines(self, samples: list[Sample]) -> Iterator[Metric]:
        poller = self.poller
        if poller is None:
            return
        transactions = CounterMetricFamily("starterbus_line_transactions", "transactions on the line", labels=["line"])
        offline = GaugeMetricFamily("starterbus_line_offline_devices", "devices not answering", labels=["line"])
        util = GaugeMetricFamily("starterbus_line_utilisation", "busy fraction of the line (0..1)", labels=["line"])
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


def start_metrics_server(address: str, collector: FleetCollector, *more: Collector) -> tuple[str, int, object]:
    """Serve ``/metrics`` on ``HOST:PORT`` (port 0: any free port); returns the host, the port and the server.
    ``more``: other collectors served beside (the service's own health)."""
    host, port = parse_host_port(address, option="--metrics")
    registry = CollectorRegistry(auto_describe=False)
    for each in (collector, *more):
        registry.register(each)
    try:
        server, _thread = start_http_server(port, host, registry)
    except OSError as exc:
        raise listen_error("--metrics", host, port, exc) from None
    return host, int(server.server_address[1]), server
