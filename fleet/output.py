"""How a fleet is shown: the live table rows, JSON lines and the CSV log."""

from __future__ import annotations

import csv
import json
import threading
from pathlib import Path
from typing import ClassVar, TextIO

from starterbus.fleet.poller import DeviceRuntime, Sample

TABLE_HEADERS = ["device", "model", "bus", "state", "fault", "I A/B/C (A)", "bus ctl", "age", "errors"]


def _currents(sample: Sample) -> str:
    if sample.status is not None and sample.status.currents:
        currents = sample.status.currents
        return "/".join(currents[p].text().removesuffix(" A") for p in ("a", "b", "c") if p in currents)
    shown = [v for k, v in sample.values.items() if v.unit == "A" and "phase" in k]
    return "/".join(v.text().removesuffix(" A") for v in shown) or "-"


def table_rows(runtimes: list[DeviceRuntime], now: float) -> list[list[str]]:
    """One row per device. An offline device shows "offline" and no values, never stale ones as fresh."""
    rows = []
    for r in runtimes:
        c = r.config
        sample = r.last_sample
        age = "-" if r.last_ok is None else f"{now - r.last_ok:.1f}s"
        if sample is None:
            rows.append([c.name, c.model, c.bus, "waiting", "", "", "", age, str(r.errors)])
            continue
        if not sample.online:
            rows.append([c.name, c.model, c.bus, "OFFLINE", (sample.error or "")[:60], "-", "-", age, str(r.errors)])
            continue
        status = sample.status
        if status is None:
            state, fault, bus = ("error" if sample.error else "?"), (sample.error or "")[:60], "-"
        else:
            state = status.state.value
            fault = f"{status.fault_code}: {status.fault_text}" if status.fault else ""
            bus = "-" if status.bus_control is None else ("yes" if status.bus_control else "no")
        rows.append([c.name, c.model, c.bus, state, fault, _currents(sample), bus, age, str(r.errors)])
    return rows


class JsonLines:
    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.lock = threading.Lock()

    def __call__(self, sample: Sample) -> None:
        with self.lock:
            self.out.write(json.dumps(sample.as_json(), ensure_ascii=False, default=str) + "\n")
            self.out.flush()


class CsvLog:
    """Long format: one row per value, plus one status row per sample (key ``status``)."""

    FIELDS: ClassVar[list[str]] = [
        "time",
        "device",
        "bus",
        "model",
        "online",
        "state",
        "fault_code",
        "fault_text",
        "key",
        "value",
        "unit",
        "resolution",
        "error",
    ]

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        new = not self.path.exists() or self.path.stat().st_size == 0
        self.file = self.path.open("a", newline="", encoding="utf-8")
        self.writer = csv.writer(self.file)
        self.lock = threading.Lock()
        if new:
            self.writer.writerow(self.FIELDS)

    def __call__(self, sample: Sample) -> None:
        status = sample.status
        base = [
            f"{sample.time:.3f}",
            sample.device,
            sample.bus,
            sample.model,
            int(sample.online),
            status.state.value if status else "",
            status.fault_code if status and status.fault else "",
            status.fault_text if status and status.fault else "",
        ]
        with self.lock:
            self.writer.writerow([*base, "status", "", "", "", sample.error or ""])
            for key, value in sample.values.items():
                self.writer.writerow([*base, key, value.value, value.unit, value.resolution, ""])
            self.file.flush()

    def close(self) -> None:
        self.file.close()
