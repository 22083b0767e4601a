"""The service's own health for Prometheus: its workers' unexpected failures and the history's writes.

Collected at scrape time from a :class:`~starterbus.core.supervision.Supervisor` and, with ``--record``, the
:class:`~starterbus.ops.history_writer.HistoryWriter`; ``poll --metrics`` and ``serve --metrics`` serve them
beside the fleet's series.
"""

from __future__ import annotations

from collections.abc import Iterator

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from starterbus.core.supervision import Supervisor
from starterbus.ops.history_writer import HistoryWriter


class ServiceCollector(Collector):
    def __init__(self, supervisor: Supervisor, history: HistoryWriter | None = None) -> None:
        self.supervisor = supervisor
        self.history = history

    def collect(self) -> Iterator[Metric]:
        failures = CounterMetricFamily(
            "starterbus_worker_failures",
            "unexpected exceptions in a worker thread or task (contained, or the one that stopped the service)",
            labels=["worker"],
        )
        for worker, count in sorted(dict(self.supervisor.failures).items()):
            failures.add_metric([worker], float(count))
        yield failures
        history = self.history
        if history is None:
            return
        yield GaugeMetricFamily(
            "starterbus_history_writable",
            "1 while the history database takes writes, 0 while writing it fails",
            value=0.0 if history.failing_since is not None else 1.0,
        )
        yield GaugeMetricFamily(
            "starterbus_history_backlog", "samples and events waiting in memory for the disk", value=history.pending
        )
        written = CounterMetricFamily("starterbus_history_written", "rows written to the history", labels=["table"])
        dropped = CounterMetricFamily(
            "starterbus_history_dropped",
            "rows dropped: more waited for the disk than the backlog holds",
            labels=["table"],
        )
        for table, ok, lost in (
            ("samples", history.written_samples, history.dropped_samples),
            ("events", history.written_events, history.dropped_events),
        ):
            written.add_metric([table], float(ok))
            dropped.add_metric([table], float(lost))
        yield written
        yield dropped
        yield CounterMetricFamily(
            "starterbus_history_write_errors", "attempts to write the history that failed", value=history.write_errors
        )
        yield CounterMetricFamily(
            "starterbus_history_outages", "episodes of the history not being writable", value=history.outages
        )
        yield CounterMetricFamily(
            "starterbus_history_moved_aside",
            "corrupted history files moved aside and started anew",
            value=len(history.moved_aside),
        )
