"""The Prometheus collector's per-line series, from a poller that counts its wire (``line_stats()``, as the
poller on main does) and from one that does not (the series are then absent, never invented)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.parser import text_string_to_metric_families

from starterbus.serve.prometheus import FleetCollector


def scrape(poller: Any) -> dict[str, dict[str, float]]:
    collector = FleetCollector()
    collector.poller = poller
    registry = CollectorRegistry(auto_describe=False)
    registry.register(collector)
    text = generate_latest(registry).decode()
    return {
        f.name: {s.labels.get("line", ""): s.value for s in f.samples} for f in text_string_to_metric_families(text)
    }


def worker(line: str, online: list[bool | None]) -> SimpleNamespace:
    return SimpleNamespace(
        bus=SimpleNamespace(name=line), transactions=7, devices=[SimpleNamespace(online=o) for o in online]
    )


def test_line_series_from_line_stats() -> None:
    wire = SimpleNamespace(requests=9, retries=2, timeouts=1, errors=1)
    stats = {"l1": SimpleNamespace(wire=wire, utilisation=0.25)}
    poller = SimpleNamespace(workers=[worker("l1", [True, False, None])], line_stats=lambda: stats)
    families = scrape(poller)
    assert families["starterbus_line_transactions"] == {"l1": 7.0}
    assert families["starterbus_line_offline_devices"] == {"l1": 1.0}
    assert (families["starterbus_line_requests"], families["starterbus_line_retries"]) == ({"l1": 9.0}, {"l1": 2.0})
    assert (families["starterbus_line_timeouts"], families["starterbus_line_errors"]) == ({"l1": 1.0}, {"l1": 1.0})
    assert families["starterbus_line_utilisation_ratio"] == {"l1": 0.25}


def test_line_series_absent_without_counts() -> None:
    families = scrape(SimpleNamespace(workers=[worker("l2", [True])]))
    assert families["starterbus_line_transactions"] == {"l2": 7.0}
    assert not {"starterbus_line_requests", "starterbus_line_utilisation_ratio"} & set(families)
