"""The fleet as the pages see it: the last sample of every device, turned into small JSON rows.

:class:`FleetView` consumes :meth:`AsyncFleet.samples` on the event loop, keeps the last sample of each device
and which devices changed, and every ``interval`` encodes the changed rows once as a server-sent event that
every connected page receives (one encoding, whatever the number of pages). Every event carries an id
(``EPOCH-SEQ``): a page that has the rows as of an id (from ``/api/fleet``, or the last event before its
connection broke) continues from it and receives only the rows changed since, as long as the view still knows
them (the last ``history`` refreshes), else a snapshot. A page that cannot keep up (its queue is full) is
disconnected; its ``EventSource`` reconnects so.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import secrets
import time
from collections import deque
from collections.abc import AsyncIterator, Callable, Iterable, Mapping
from typing import Any

from starterbus.core.errors import StarterbusError
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile
from starterbus.fleet.config import FleetConfig
from starterbus.fleet.line_stats import LineStats
from starterbus.fleet.sample import Sample

LineSource = Callable[[], Mapping[str, LineStats]]


def _profile(model: str, cache: dict[str, Profile | None]) -> Profile | None:
    if model not in cache:
        try:
            cache[model] = get_profile(model)
        except StarterbusError:
            cache[model] = None
    return cache[model]


def device_row(sample: Sample, profile: Profile | None, offline_since: float | None) -> dict[str, Any]:
    """One device's row of the fleet page: state, fault (English and Chinese), currents, when it last answered."""
    status = sample.status if sample.online else None
    fault: dict[str, Any] | None = None
    if status is not None and status.fault:
        code = status.fault_code
        label = profile.faults.label(code) if profile is not None and code is not None else None
        fault = {
            "code": code,
            "en": label.en if label else (status.fault_text or ""),
            "zh": label.zh if label else "",
        }
    currents = {k: v.value for k, v in status.currents.items()} if status is not None else {}
    if status is not None and not currents and profile is not None:  # the fleet file polls them as measurements
        for name, point in zip("abc", profile.phase_currents(), strict=False):
            if point.key in sample.values:
                currents[name] = sample.values[point.key].value
    return {
        "name": sample.device,
        "line": sample.bus,
        "model": sample.model,
        "online": sample.online,
        "state": status.state.value if status is not None else ("unknown" if sample.online else "offline"),
        "fault": fault,
        "currents": currents,
        "time": round(sample.time, 3),
        "offline_since": offline_since,
        "error": sample.error,
    }


class FleetView:
    """The last sample per device, and the server-sent events that carry its changes to the pages."""

    def __init__(
        self,
        config: FleetConfig,
        lines: LineSource | None = None,
        *,
        interval: float = 0.5,
        queue_size: int = 64,
        history: int = 32,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.config = config
        self.lines = lines
        self.interval = interval
        self.queue_size = queue_size
        self.clock = clock
        self.samples: dict[str, Sample] = {}
        self.rows: dict[str, dict[str, Any]] = {}
        self._offline_since: dict[str, float | None] = {}
        self._dirty: set[str] = set()
        self._profiles: dict[str, Profile | None] = {}
        self._clients: set[asyncio.Queue[bytes | None]] = set()
        self._watching: dict[asyncio.Queue[bytes | None], str] = {}  # a device page's queue -> its device
        self.events_sent = 0
        self.clients_dropped = 0
        self.epoch = secrets.token_hex(4)  # event ids of another process (a restarted server) are not ours
        self.seq = 0
        self._changes: deque[tuple[int, frozenset[str]]] = deque(maxlen=history)
        for device in config.devices:  # every configured device is on the page before its first poll
            self.rows[device.name] = {
                "name": device.name,
                "line": device.bus,
                "model": device.model,
                "online": None,
                "state": "unknown",
                "fault": None,
                "currents": {},
                "time": None,
                "offline_since": None,
                "error": None,
            }

    # -- in ------------------------------------------------------------------------------------------------

    def observe(self, sample: Sample) -> None:
        """Take one sample (on the event loop); cheap: the row is made once per flush, not per sample."""
        name = sample.device
        if not sample.online:
            if self._offline_since.get(name) is None:
                self._offline_since[name] = sample.time
        else:
            self._offline_since[name] = None
        self.samples[name] = sample
        self._dirty.add(name)

    async def consume(self, samples: AsyncIterator[Sample]) -> None:
        async for sample in samples:
            self.observe(sample)

    # -- out -----------------------------------------------------------------------------------------------

    def _refresh(self) -> list[str]:
        """Make the rows of the devices sampled since the last refresh; their names."""
        if not self._dirty:
            return []
        changed = list(self._dirty)
        for name in changed:
            sample = self.samples[name]
            row = device_row(sample, _profile(sample.model, self._profiles), self._offline_since.get(name))
            self.rows[name] = row
        self._dirty.clear()
        self.seq += 1
        self._changes.append((self.seq, frozenset(changed)))
        return changed

    @property
    def event_id(self) -> str:
        """Names the rows as they are now: the stream continues from it (``/api/stream?after=ID``)."""
        return f"{self.epoch}-{self.seq}"

    def line_rows(self) -> list[dict[str, Any]]:
        stats = self.lines() if self.lines is not None else {}
        out = []
        for bus in self.config.buses:
            line = stats.get(bus.name)
            out.append(
                {
                    "name": bus.name,
                    "transport": bus.transport,
                    "devices": len(bus.devices),
                    "utilisation": round(line.utilisation, 4) if line is not None else None,
                }
            )
        return out

    def _payload(self, names: Iterable[str], with_id: bool) -> str:
        """``{"now", "devices", "lines"}`` (and ``"id"``) as compact JSON: one encoding of the rows named."""
        payload: dict[str, Any] = {"id": self.event_id} if with_id else {}
        payload.update(now=self.clock(), devices=[self.rows[name] for name in names], lines=self.line_rows())
        return _encode(payload)

    def snapshot(self) -> dict[str, Any]:
        self._refresh_into_rows()
        return {
            "id": self.event_id,
            "now": self.clock(),
            "devices": list(self.rows.values()),
            "lines": self.line_rows(),
        }

    def snapshot_json(self) -> str:
        """:meth:`snapshot` as compact JSON text."""
        self._refresh_into_rows()
        return self._payload(self.rows, with_id=True)

    def _refresh_into_rows(self) -> None:
        if self._dirty:
            self._broadcast(self._refresh())

    def _broadcast(self, changed: list[str]) -> None:
        if not self._clients:
            return
        messages: dict[str | None, bytes] = {}  # one encoding for the fleet pages, one per device watched

        def message(device: str | None) -> bytes:
            if device not in messages:
                names = changed if device is None else [device] if device in changed else []
                messages[device] = sse("update", self._payload(names, with_id=False), self.event_id)
            return messages[device]

        self.events_sent += 1
        for queue in list(self._clients):
            try:
                queue.put_nowait(message(self._watching.get(queue)))
            except asyncio.QueueFull:
                self.clients_dropped += 1
                self._clients.discard(queue)
                self._watching.pop(queue, None)
                with contextlib.suppress(asyncio.QueueFull):
                    queue.get_nowait()
                    queue.put_nowait(None)  # tells the stream to end; the page reconnects from its last event id

    def flush(self) -> None:
        """Send what changed since the last flush (the line utilisation at least, as a heartbeat)."""
        self._broadcast(self._refresh())

    async def run_flusher(self, stop: asyncio.Event) -> None:
        while not stop.is_set():
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(stop.wait(), self.interval)
            self.flush()

    def changed_since(self, event_id: str) -> list[str] | None:
        """The devices whose rows changed after ``event_id``; None if it is not known here (another process, or
        older than the changes kept): then only a snapshot will do."""
        epoch, _, number = event_id.partition("-")
        if epoch != self.epoch or not number.isdigit() or int(number) > self.seq:
            return None
        after = int(number)
        if after < self.seq and (not self._changes or self._changes[0][0] > after + 1):
            return None
        names: set[str] = set()
        for seq, changed in self._changes:
            if seq > after:
                names |= changed
        return sorted(names)

    def subscribe(self, after: str | None = None, device: str | None = None) -> asyncio.Queue[bytes | None]:
        """A new page: its queue starts with the snapshot or, for a page that has the rows as of event ``after``
        (from ``/api/fleet``, or its stream's last event before a reconnection), with only what changed since.
        ``device`` (a device page): only that device's row, in the snapshot and in every update (an update with
        no row when it did not change: the line utilisation, and a heartbeat)."""
        if device is not None and device not in self.rows:
            raise KeyError(device)
        self._refresh_into_rows()
        queue: asyncio.Queue[bytes | None] = asyncio.Queue(self.queue_size)
        changed = self.changed_since(after) if after else None
        names = list(self.rows) if device is None else [device]
        if changed is None:
            queue.put_nowait(sse("snapshot", self._payload(names, with_id=True), self.event_id))
        elif changed := [name for name in changed if name in names]:
            queue.put_nowait(sse("update", self._payload(changed, with_id=False), self.event_id))
        self._clients.add(queue)
        if device is not None:
            self._watching[queue] = device
        return queue

    def unsubscribe(self, queue: asyncio.Queue[bytes | None]) -> None:
        self._clients.discard(queue)
        self._watching.pop(queue, None)

    @property
    def clients(self) -> int:
        return len(self._clients)


def _encode(value: object) -> str:
    return json.dumps(value, ensure_ascii=False, separators=(",", ":"))


def sse(event: str, data: str, event_id: str | None = None) -> bytes:
    """One server-sent event (``data`` is one line: compact JSON); with ``id`` the browser reconnects from it."""
    head = f"id: {event_id}\n" if event_id is not None else ""
    return f"{head}event: {event}\ndata: {data}\n\n".encode()
