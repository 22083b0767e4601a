"""The ``--metrics`` endpoint by Prometheus's conventions: one family per unit, in base units, checked by
``promtool check metrics`` (Debian package ``prometheus``) on a scrape over HTTP of every point of every
built-in profile, the edge node's series, the line counters, the service's health and the process collectors."""

from __future__ import annotations

import shutil
import subprocess
import urllib.request
from types import SimpleNamespace

import pytest
from prometheus_client.parser import text_string_to_metric_families

from starterbus.core.model import Value
from starterbus.core.registry import get_profile
from starterbus.core.status import decode_status_word
from starterbus.core.supervision import Supervisor
from starterbus.fleet.poller import Sample
from starterbus.ops.service_metrics import ServiceCollector
from starterbus.serve.metrics import Aliases, node_metrics
from starterbus.serve.prometheus import FleetCollector, start_metrics_server, value_family
from starterbus.serve.session import EdgeSession, SessionOptions

MODELS = ("jjr5000", "ssd1", "jjr8000")


def every_point(model: str) -> Sample:
    """One good poll of a ``model`` device that read every point of its profile, each at its raw maximum."""
    profile = get_profile(model)
    values = {p.key: Value.from_raw(p, p.raw_max) for p in profile.points.values()}
    status = decode_status_word(0x2000, profile.faults)
    return Sample(f"dev-{model}", "line-1", model, 1_800_000_000.0, True, status, values, None, 0)


def scrape() -> str:
    session = EdgeSession(SessionOptions("g", "n"), node_metrics(Aliases()), {})
    collector = FleetCollector(session)
    wire = SimpleNamespace(requests=9, retries=2, timeouts=1, errors=1)
    worker = SimpleNamespace(bus=SimpleNamespace(name="line-1"), transactions=7, devices=[SimpleNamespace(online=True)])
    collector.poller = SimpleNamespace(  # type: ignore[assignment]
        workers=[worker], line_stats=lambda: {"line-1": SimpleNamespace(wire=wire, utilisation=0.25)}
    )
    for model in MODELS:
        collector.observe(every_point(model))
    _host, port, server = start_metrics_server("127.0.0.1:0", collector, ServiceCollector(Supervisor()))
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10) as answer:
            return str(answer.read().decode())
    finally:
        server.close()


def test_promtool_check_metrics_passes_on_a_scrape() -> None:
    promtool = shutil.which("promtool")
    if promtool is None:
        pytest.skip("promtool is not installed (apt-get install prometheus)")
    text = scrape()
    checked = subprocess.run(
        [promtool, "check", "metrics"], check=False, input=text, capture_output=True, text=True, timeout=60
    )
    assert (checked.returncode, checked.stdout + checked.stderr) == (0, ""), text
    assert "starterbus_line_utilisation_ratio" in text and "process_resident_memory_bytes" in text


def test_one_family_per_unit_in_base_units() -> None:
    families = {f.name: f for f in text_string_to_metric_families(scrape())}
    values = {name: f for name, f in families.items() if name.startswith("starterbus_device_value")}
    assert set(values) == {
        "starterbus_device_value",
        "starterbus_device_value_amperes",
        "starterbus_device_value_percent",
        "starterbus_device_value_ratio",
        "starterbus_device_value_seconds",
        "starterbus_device_value_celsius",
        "starterbus_device_value_cycles",
    }
    by_family: dict[str, set[str]] = {}
    for model in MODELS:
        for point in get_profile(model).points.values():
            by_family.setdefault(value_family(point.unit)[0], set()).add(point.unit)
    assert by_family["starterbus_device_value_seconds"] == {"s", "min", "h"}  # converted, not mixed
    assert all(len(units) == 1 for name, units in by_family.items() if name != "starterbus_device_value_seconds")
    assert all(set(s.labels) == {"device", "key"} for f in values.values() for s in f.samples)

    def value(family: str, key: str) -> float:
        (sample,) = [s for s in values[family].samples if s.labels == {"device": "dev-jjr8000", "key": key}]
        return float(sample.value)

    profile = get_profile("jjr8000")
    assert value("starterbus_device_value_seconds", "lcd_off_time") == profile.point("lcd_off_time").raw_max * 60
    assert value("starterbus_device_value_seconds", "run_time") == profile.point("run_time").raw_max * 3600
    assert value("starterbus_device_value_ratio", "current_limit") == pytest.approx(5.0)  # 500 x 0.01 In
    assert value_family("kW") == ("starterbus_device_value_kw", 1.0)  # a plugin's unit: a family of its own
