"""How a fleet is shown: the live table rows, JSON lines and the CSV log.

States have the names of :class:`~starterbus.core.status.MotorState`, as in every other output: an idle motor
is ``ready`` (status word bit 13 set) or ``stopped`` (not known to be ready; the ``ready`` column says ``no``, or
``-`` where the path does not tell, as DeviceNet's assemblies). Device faults and communication errors have
columns of their own; a long error is shortened at a word boundary, never mid-word.
"""

from __future__ import annotations

import csv
import json
import sys
import textwrap
import threading
from pathlib import Path
from typing import TextIO

from starterbus.core.errors import ConfigurationError, StarterbusError
from starterbus.core.fault_codes import value_text
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.status import Status
from starterbus.core.timestamps import iso_time
from starterbus.fleet.config import FleetConfig
from starterbus.fleet.poller import DeviceRuntime, Sample

TABLE_HEADERS = ["device", "model", "bus", "state", "ready", "fault", "I A/B/C (A)", "points", "bus ctl", "age",
                 "errors", "communication"]  # fmt: skip
ERROR_WIDTH = 48


def display_state(status: Status) -> str:
    """The state's one name (:class:`~starterbus.core.status.MotorState`), the same as JSON, history and serve."""
    return status.state.value


def _flag(value: bool | None) -> str:
    return "-" if value is None else ("yes" if value else "no")


def _currents(sample: Sample) -> str:
    if sample.status is not None and sample.status.currents:
        currents = sample.status.currents
        return "/".join(currents[p].text().removesuffix(" A") for p in ("a", "b", "c") if p in currents)
    shown = [v for k, v in sample.values.items() if v.unit == "A" and "phase" in k]
    return "/".join(v.text().removesuffix(" A") for v in shown) or "-"


def _points(sample: Sample, profile: Profile | None) -> str:
    """The configured points besides the phase currents (those have their own column); fault codes (the
    device's fault history) decoded with the profile's fault table, as the status's fault is."""
    return ", ".join(
        f"{k} {v.text() if profile is None else value_text(profile, v)}"
        for k, v in sample.values.items()
        if not (v.unit == "A" and "phase" in k)
    )


def _profile(runtime: DeviceRuntime) -> Profile | None:
    """The device's profile, to decode fault codes (after the last poll the device is closed)."""
    if runtime.device is not None:
        return runtime.device.profile
    try:
        return get_profile(runtime.config.model)
    except StarterbusError:
        return None


def shorten(text: str, width: int = ERROR_WIDTH) -> str:
    return textwrap.shorten(" ".join(text.split()), width=width, placeholder=" …") if text else ""


def table_rows(runtimes: list[DeviceRuntime], now: float) -> list[list[str]]:
    """One row per device. An offline device shows "offline" and no values, never stale ones as fresh."""
    return [row for row, _ in table_rows_styled(runtimes, now)]


def table_rows_styled(runtimes: list[DeviceRuntime], now: float) -> list[tuple[list[str], str | None]]:
    """Rows with a style each (``fault``, ``offline``, ``warning`` or None) for colour on a terminal."""
    rows: list[tuple[list[str], str | None]] = []
    for r in runtimes:
        c = r.config
        sample = r.last_sample
        age = "-" if r.last_ok is None else f"{now - r.last_ok:.1f}s"
        head = [c.name, c.model, c.bus]
        if sample is None:
            rows.append(([*head, "waiting", "", "", "", "", "", age, str(r.errors), ""], None))
            continue
        if not sample.online:
            comm = shorten(sample.error or "")
            rows.append(([*head, "offline", "-", "", "-", "", "-", age, str(r.errors), comm], "offline"))
            continue
        status = sample.status
        comm = shorten(sample.error or "")
        points = _points(sample, _profile(r))
        if status is None:
            rows.append(([*head, "?", "-", "", _currents(sample), points, "-", age, str(r.errors), comm],
                         "warning" if comm else None))  # fmt: skip
            continue
        fault = f"{status.fault_code}: {status.fault_text}" if status.fault else ""
        style = "fault" if status.fault else ("warning" if status.warning or comm else None)
        cells = [display_state(status), _flag(status.ready), fault, _currents(sample), points]
        cells += [_flag(status.bus_control), age, str(r.errors), comm]
        rows.append(([*head, *cells], style))
    return rows


class JsonLines:
    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.lock = threading.Lock()
        self.closed = False  # the reader went away (`| head`): stop writing, quietly

    def __call__(self, sample: Sample) -> None:
        with self.lock:
            if self.closed:
                return
            try:
                self.out.write(json.dumps(sample.as_json(), ensure_ascii=False, default=str) + "\n")
                self.out.flush()
            except BrokenPipeError:
                self.closed = True

    def event(self, data: dict[str, object]) -> None:
        """One line that is not a sample (``{"event": "history", ...}``), between the samples (any thread)."""
        with self.lock:
            if self.closed:
                return
            try:
                self.out.write(json.dumps(data, ensure_ascii=False, default=str) + "\n")
                self.out.flush()
            except BrokenPipeError:
                self.closed = True


class CsvLog:
    """Wide format (default): one row per sample, one column per configured point (``key [unit]``).

    ``long=True``: one row per value plus one status row per sample (key ``status``). Times are ISO 8601 in UTC
    (:func:`~starterbus.core.timestamps.iso_time`). Appending to a file whose header is another layout is refused,
    so columns never shift under a reader. Path ``-``: standard output (header first; a closed pipe sets
    ``closed``).
    """

    BASE = ("time", "device", "bus", "model", "online", "state", "ready", "fault_code", "fault_text", "error")
    LONG = (*BASE[:-1], "key", "value", "unit", "resolution", "error")

    def __init__(self, path: str | Path, config: FleetConfig | None = None, *, long: bool = False) -> None:
        self.path = Path(path)
        self.to_stdout = str(path) == "-"
        self.closed = False
        self.long = long or config is None
        self.keys: list[str] = []
        if not self.long and config is not None:
            for device in config.devices:
                for key in (*device.measurements, *device.parameters):
                    if key not in self.keys:
                        self.keys.append(key)
        self.header = list(self.LONG) if self.long else [*self.BASE, *self.keys]
        new = self.to_stdout or not self.path.exists() or self.path.stat().st_size == 0
        if not new:
            with self.path.open(encoding="utf-8", newline="") as f:
                existing = next(csv.reader(f), [])
            if existing != self.header:
                raise ConfigurationError(
                    f"{self.path}: its header is another layout ({', '.join(existing[:6])}, ...); "
                    "append to a log of the same fleet and format, or give a new file"
                )
        self.file = sys.stdout if self.to_stdout else self.path.open("a", newline="", encoding="utf-8")
        self.writer = csv.writer(self.file)
        self.lock = threading.Lock()
        if new:
            self.writer.writerow(self.header)

    def __call__(self, sample: Sample) -> None:
        status = sample.status
        base = [
            iso_time(sample.time),
            sample.device,
            sample.bus,
            sample.model,
            int(sample.online),
            display_state(status) if status else ("" if sample.online else "offline"),
            "" if status is None or status.ready is None else int(status.ready),
            status.fault_code if status and status.fault else "",
            status.fault_text if status and status.fault else "",
        ]
        with self.lock:
            if self.closed:
                return
            try:
                if self.long:
                    self.writer.writerow([*base, "status", "", "", "", sample.error or ""])
                    for key, value in sample.values.items():
                        self.writer.writerow([*base, key, value.value, value.unit, value.resolution, ""])
                else:
                    values = [sample.values[k].value if k in sample.values else "" for k in self.keys]
                    self.writer.writerow([*base, sample.error or "", *values])
                self.file.flush()
            except BrokenPipeError:
                if not self.to_stdout:
                    raise
                self.closed = True  # the reader of stdout went away (`| head`): stop writing, quietly

    def close(self) -> None:
        if not self.to_stdout:
            self.file.close()
