"""Turning a stream of fleet samples (and the audit trail) into history: samples plus events.

:class:`HistoryRecorder` is an ``on_sample`` callable for :class:`~starterbus.fleet.poller.FleetPoller` (and
anything else that produces :class:`~starterbus.fleet.poller.Sample`)::

    recorder = HistoryRecorder("plant.db", retention=Retention(max_age=30 * 86400), audit=AuditLog())
    poller = FleetPoller(config, recorder)      # or call recorder(sample) from your own sink
    ...
    recorder.close()

Events it writes: ``state`` (every change of the motor state), ``fault`` (code, text from the profile's fault
table, and the phase currents of the last samples before the trip), ``offline``/``online`` episodes, and every
guarded ``write`` and ``command`` found in the audit trail (followed from where it ended when recording began)
or handed over with :meth:`HistoryRecorder.record_audit`.

The rows are written by a :class:`~starterbus.ops.history_writer.HistoryWriter` in a thread of its own: a
call never waits for the disk, and a disk that fails (full, read-only, gone, a locked or corrupted database)
stops nothing; the gap is recorded once the history can be written again.
"""

from __future__ import annotations

import json
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from starterbus.core.audit import AuditLog
from starterbus.core.errors import ConfigurationError, StarterbusError
from starterbus.core.fault_codes import value_text
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.core.status import Command
from starterbus.core.supervision import Supervisor
from starterbus.core.timestamps import parse_iso_time
from starterbus.core.url import DeviceUrl
from starterbus.fleet.config import FleetConfig
from starterbus.fleet.poller import Sample
from starterbus.ops.history import Retention
from starterbus.ops.history_writer import DEFAULT_BACKLOG, DEFAULT_RETRY, HistoryWriter

_BEFORE_TRIP = 5  # samples of currents kept per device for a fault event


@dataclass
class _Track:
    state: str | None = None
    online: bool | None = None
    offline_since: float | None = None
    currents: deque[dict[str, Any]] = field(default_factory=lambda: deque(maxlen=_BEFORE_TRIP))


def sample_row(sample: Sample, profile: Profile | None) -> dict[str, Any]:
    """The ``samples`` row of one poll; fault-code values carry their text from the profile's fault table."""
    status = sample.status
    currents = {k: v.value for k, v in status.currents.items()} if status is not None else {}
    values: dict[str, Any] = {}
    for key, value in sample.values.items():
        values[key] = {
            "value": value.value,
            "raw": value.raw,
            "unit": value.unit,
            "text": value_text(profile, value) if profile is not None else value.text(),
        }
    return {
        "time": sample.time,
        "device": sample.device,
        "model": sample.model,
        "online": int(sample.online),
        "state": status.state.value if status is not None else None,
        "fault_code": status.fault_code if status is not None and status.fault else None,
        "current_a": currents.get("a"),
        "current_b": currents.get("b"),
        "current_c": currents.get("c"),
        "values": values,
        "error": sample.error,
    }


class HistoryRecorder:
    """Writes samples and events to a history database; call it with each :class:`Sample`."""

    def __init__(
        self,
        path: str | Path,
        *,
        retention: Retention | None = None,
        audit: AuditLog | None = None,
        devices: Mapping[str, str] | None = None,
        prune_every: float = 60.0,
        backlog: int = DEFAULT_BACKLOG,
        retry: float = DEFAULT_RETRY,
        supervisor: Supervisor | None = None,
        on_event: Callable[[dict[str, Any]], None] | None = None,
    ) -> None:
        """``audit``: follow this audit log from its current end; ``devices``: device URL -> fleet name, to name
        the device of an audit record (else its URL is the name); ``backlog``, ``retry``, ``on_event``: see
        :class:`~starterbus.ops.history_writer.HistoryWriter`."""
        self.writer = HistoryWriter(
            path,
            retention=retention,
            backlog=backlog,
            retry=retry,
            prune_every=prune_every,
            supervisor=supervisor,
            on_event=on_event,
        )
        self.audit_path = audit.path if audit is not None else None
        self._audit_offset = self._size(self.audit_path)
        self.devices = dict(devices or {})
        self._tracks: dict[str, _Track] = {}
        self._profiles: dict[str, Profile | None] = {}
        self._lock = threading.Lock()
        self.samples = 0

    @property
    def path(self) -> Path:
        return self.writer.path

    def close(self) -> None:
        """Write what waits (see :meth:`HistoryWriter.close`) and close the file."""
        self.follow_audit()
        self.writer.close()

    def __enter__(self) -> HistoryRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _profile(self, model: str) -> Profile | None:
        if model not in self._profiles:
            try:
                self._profiles[model] = get_profile(model)
            except StarterbusError:
                self._profiles[model] = None
        return self._profiles[model]

    # -- samples ------------------------------------------------------------------------------------------

    def __call__(self, sample: Sample) -> None:
        with self._lock:
            row = sample_row(sample, self._profile(sample.model))
            self.writer.add([row], self._events(sample))
            self.samples += 1
        self.follow_audit()

    def _events(self, sample: Sample) -> list[dict[str, Any]]:
        track = self._tracks.setdefault(sample.device, _Track())
        name, now = sample.device, sample.time
        events: list[dict[str, Any]] = []

        def event(kind: str, text: str, **more: Any) -> None:
            events.append({"time": now, "device": name, "kind": kind, "text": text, **more})

        if not sample.online:
            if track.online is not False:
                track.offline_since = now
                event("offline", sample.error or "no answer")
            track.online = False
            return events
        if track.online is False:
            away = now - track.offline_since if track.offline_since is not None else 0.0
            event("online", f"answering again after {away:.1f} s", detail={"offline_s": away})
        track.online = True
        status = sample.status
        if status is None:
            return events
        state = status.state.value
        if track.state is not None and state != track.state:
            event("state", f"{track.state} -> {state}", detail={"from": track.state, "to": state})
        if status.fault and track.state != state:
            code = status.fault_code
            profile = self._profile(sample.model)
            text = status.fault_text or (profile.faults.text(code) if profile and code is not None else "")
            event("fault", f"{code}: {text}", code=code, detail={"currents_before": list(track.currents)})
        track.state = state
        if status.currents:
            track.currents.append({"time": now, **{k: v.value for k, v in status.currents.items()}})
        return events

    # -- the audit trail ----------------------------------------------------------------------------------

    def record_audit(self, entry: Mapping[str, object]) -> None:
        """Write one audit record (a guarded write or command, as :class:`AuditLog` appends it) as an event."""
        device = str(entry.get("device", "?"))
        name = self.devices.get(device, device)
        when = _audit_time(entry)
        result = str(entry.get("result", ""))
        action = str(entry.get("action", "command"))
        kind = "command" if action in _COMMANDS else action
        if "key" in entry:
            text = f"{entry.get('key')}: {entry.get('old')} -> {entry.get('new')}: {result}"
        elif "before" in entry or "reached" in entry:
            text = f"{entry.get('command', action)}: {entry.get('before')} -> {entry.get('reached')}: {result}"
        else:  # refused before anything was sent: not confirmed (the question), a refused DCMD (what it asked)
            asked = str(entry.get("what") or entry.get("asked") or entry.get("command") or action).rstrip("?")
            text = f"{asked}: {result}"
        with self._lock:
            self.writer.add([], [{"time": when, "device": name, "kind": kind, "text": text, "detail": dict(entry)}])

    def follow_audit(self) -> None:
        """Read the audit records appended since the last call (or since recording began)."""
        if self.audit_path is None or self._size(self.audit_path) <= self._audit_offset:
            return
        with self.audit_path.open("rb") as f:
            f.seek(self._audit_offset)
            chunk = f.read()
        end = chunk.rfind(b"\n") + 1  # a line still being written waits for the next call
        self._audit_offset += end
        for line in chunk[:end].splitlines():
            try:
                entry = json.loads(line)
            except ValueError:
                continue
            if isinstance(entry, dict):
                self.record_audit(entry)

    @staticmethod
    def _size(path: Path | None) -> int:
        try:
            return path.stat().st_size if path is not None else 0
        except OSError:
            return 0


def _audit_time(entry: Mapping[str, object]) -> float:
    text = str(entry.get("time", ""))
    try:
        return parse_iso_time(text) if text else time.time()  # the zone it was written with
    except ValueError:
        return time.time()


_COMMANDS = {"command", *(c.value for c in Command)}  # a command's record, or a command not confirmed
_AGE_UNITS = {"s": 1.0, "m": 60.0, "h": 3600.0, "d": 86400.0, "w": 604800.0}
_SIZE_UNITS = {"kb": 1e3, "mb": 1e6, "gb": 1e9, "kib": 1024.0, "mib": 1024.0**2, "gib": 1024.0**3}


def parse_keep(texts: list[str] | None) -> Retention:
    """``--keep 30d --keep 500MB``: an age (s, m, h, d, w) and/or a size (kB, MB, GB, KiB, MiB, GiB)."""
    max_age: float | None = None
    max_bytes: int | None = None
    for text in texts or []:
        t = text.strip().lower()
        number = t.rstrip("abcdefghijklmnopqrstuvwxyz")
        unit = t[len(number) :]
        try:
            amount = float(number)
        except ValueError:
            amount = -1.0
        if amount > 0 and unit in _AGE_UNITS:
            max_age = amount * _AGE_UNITS[unit]
        elif amount > 0 and unit in _SIZE_UNITS:
            max_bytes = int(amount * _SIZE_UNITS[unit])
        else:
            raise ConfigurationError(f"--keep {text!r}: give an age like 30d or 12h, or a size like 500MB")
    return Retention(max_age, max_bytes)


def for_fleet(
    path: str | Path,
    config: FleetConfig,
    keep: list[str] | None = None,
    *,
    backlog: int = DEFAULT_BACKLOG,
    supervisor: Supervisor | None = None,
) -> HistoryRecorder:
    """The recorder ``poll --record`` uses: the fleet's device names, the user's audit log followed."""
    names: dict[str, str] = {}
    for bus in config.buses:
        for dev in bus.devices:
            names[dev.url] = dev.name
            try:
                names[DeviceUrl.parse(dev.url).text] = dev.name
            except StarterbusError:
                pass
    return HistoryRecorder(
        path, retention=parse_keep(keep), audit=AuditLog(), devices=names, backlog=backlog, supervisor=supervisor
    )
