"""What a device page shows: the profile's points with their facts, the last values, the history database.

Reading the history runs in a worker thread (SQLite is blocking I/O); everything else here is pure.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from starterbus.core.errors import ConfigurationError
from starterbus.core.fault_codes import value_text
from starterbus.core.model import Certainty, PointDef, Value
from starterbus.core.profile import Profile
from starterbus.fleet.config import DeviceConfig
from starterbus.fleet.sample import Sample
from starterbus.ops import diff
from starterbus.ops.backup import Backup
from starterbus.ops.history import HistoryStore
from starterbus.ops.plot import _peak, event_window

_ORDER = (Certainty.PRINTED, Certainty.INFERRED, Certainty.ASSUMED)
#: the history's own columns of the phase currents
CURRENT_COLUMNS = {"current_a": "a", "current_b": "b", "current_c": "c"}
MAX_POINTS = 4000  # a series longer than this is thinned (every n-th row) before it is sent


def certainty(point: PointDef) -> dict[str, str]:
    """The least certain of the point's address, scale (or codes), and why."""
    found = [point.address_source]
    if point.enum is not None:
        found += [point.enum.provenance(k) for k in point.enum.labels if point.raw_min <= k <= point.raw_max]
    else:
        found.append(point.scale_source)
    weakest = max(found, key=lambda p: _ORDER.index(p.certainty))
    return weakest.as_json()


def point_facts(point: PointDef) -> dict[str, Any]:
    lo, hi = point.to_engineering(point.raw_min), point.to_engineering(point.raw_max)
    return {
        "key": point.key,
        "kind": point.kind.value,
        "address": point.address,
        "en": point.name_en,
        "zh": point.name_zh,
        "unit": point.unit,
        "min": lo,
        "max": hi,
        "step": point.scale,
        "writable": point.writable,
        "default": point.to_engineering(point.default) if point.default is not None and point.enum is None else None,
        "choices": (
            {str(k): {"en": v.en, "zh": v.zh} for k, v in sorted(point.enum.labels.items())}
            if point.enum is not None
            else None
        ),
        "certainty": certainty(point),
    }


def value_json(profile: Profile, value: Value) -> dict[str, Any]:
    label = value.label
    return {
        "value": value.value,
        "raw": value.raw,
        "text": value_text(profile, value),
        "zh": label.zh if label is not None else None,
        "resolution": value.resolution,
    }


def device_detail(
    config: DeviceConfig, profile: Profile, sample: Sample | None, row: Mapping[str, Any]
) -> dict[str, Any]:
    """The device page's data: configuration, every point of the profile, the last values and status."""
    values = sample.values if sample is not None else {}
    status = sample.status if sample is not None and sample.online else None
    return {
        "name": config.name,
        "line": config.bus,
        "model": profile.name,
        "display_name": profile.display_name,
        "vendor": profile.vendor,
        "period": config.period,
        "row": dict(row),
        "status": status.as_json() if status is not None else None,
        "remote": {
            "commands": sorted(c.value for c in config.remote.commands),
            "write": sorted(config.remote.write),
        },
        "points": [
            {**point_facts(p), "now": value_json(profile, values[p.key]) if p.key in values else None}
            for p in profile.points.values()
        ],
    }


# -- the history database (call these in a worker thread) ---------------------------------------------------


def _open(db: Path) -> HistoryStore:
    if not db.exists():
        raise ConfigurationError(f"{db}: no history yet")
    return HistoryStore(db, create=False)


def events(
    db: Path,
    device: str,
    since: float | None,
    after: int | None = None,
    limit: int = 500,
    profile: Profile | None = None,
) -> list[dict[str, Any]]:
    """The device's last ``limit`` events (since time ``since``; written after event id ``after``: what a page
    that shows the events up to ``after`` has not seen, even an event of an earlier time written late). With the
    device's ``profile``, a fault has its text in Chinese too (``zh``)."""
    with _open(db) as store:
        rows = store.events(device=device, since=since, after=after, limit=limit)
    out = [_jsonable_event(e) for e in rows]
    for event in out:
        if profile is not None and event["kind"] == "fault" and isinstance(event["code"], int):
            event["zh"] = f"{event['code']}: {profile.faults.label(event['code']).zh}"
    return out


def _jsonable_event(event: Mapping[str, Any]) -> dict[str, Any]:
    detail = event.get("detail") or {}
    return {
        "id": event["id"],
        "time": event["time"],
        "kind": event["kind"],
        "code": event["code"],
        "text": event["text"],
        "actor": detail.get("actor"),
        "user": detail.get("user"),  # an audit record's: the account of the process that wrote it
        "currents_before": detail.get("currents_before"),
    }


def starts(db: Path, device: str) -> list[dict[str, Any]]:
    """Recorded starts (``record``) and the starts the poll saw (a state change into starting)."""
    with _open(db) as store:
        rows = store.events(device=device, kind="start") + [
            e for e in store.events(device=device, kind="state") if (e["detail"] or {}).get("to") == "starting"
        ]
    return sorted((_jsonable_event(e) for e in rows), key=lambda e: e["time"])


def start_plot(db: Path, device: str, event_id: int) -> dict[str, Any]:
    """The samples of one start as columns (t, a, b, c, state), the current limit and the peak."""
    event, points, limit_a = event_window(db, device, event_id)
    peak = _peak(points, since=None if event["kind"] == "fault" else 0.0)
    return {
        "event": _jsonable_event(event),
        "t": [p.t for p in points],
        "a": [p.currents.get("a") for p in points],
        "b": [p.currents.get("b") for p in points],
        "c": [p.currents.get("c") for p in points],
        "state": [p.state for p in points],
        "limit_a": limit_a,
        "peak": {"t": peak[0], "amps": peak[1], "phase": peak[2]} if peak is not None else None,
    }


def series(db: Path, device: str, key: str, since: float | None, until: float | None) -> dict[str, Any]:
    """A measured point over time: the phase-current columns, or a polled value from the samples' values."""
    with _open(db) as store:
        rows = store.samples(device=device, since=since, until=until)
    step = max(1, math.ceil(len(rows) / MAX_POINTS))
    t: list[float] = []
    v: list[float | None] = []
    for row in rows[::step]:
        if key in CURRENT_COLUMNS:
            value = row[key]
        else:
            entry = row["values"].get(key)
            value = entry.get("value") if isinstance(entry, Mapping) else None
        t.append(row["time"])
        v.append(value if isinstance(value, (int, float)) else None)
    return {"key": key, "t": t, "v": v, "thinned": step}


def history_keys(db: Path, device: str) -> list[str]:
    """The points with a history: the phase currents and the polled values of the last sample."""
    with _open(db) as store:
        last = store.samples(device=device, limit=1)
    keys = list(CURRENT_COLUMNS)
    if last:
        for key, entry in last[0]["values"].items():
            if isinstance(entry, Mapping) and isinstance(entry.get("value"), (int, float)):
                keys.append(key)
    return keys


def backup_diff(backup: Backup, profile: Profile) -> list[dict[str, object]]:
    """The device's parameters against the profile's defaults (only what differs)."""
    device_side = diff.ParameterSet("device", profile, backup.raws())
    return [r.as_json() for r in diff.compare(diff.from_defaults(profile), device_side)]
