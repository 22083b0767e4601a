"""The store-and-forward buffer of the edge session: what it asks of a store, and the store kept in memory.

While no session is up, the changed values of a device are kept as one record per would-be DDATA: the device
name and its metrics by *name* (not alias: aliases are numbered from the fleet file, which may change between
a stop and a restart). Records leave the store oldest first, once their device is born again, and are removed
only once written (:meth:`HistoryStore.remove`); the bounds (count, size, age) drop the oldest and count them.
``store.SqliteStore`` keeps the same records on disk so that they survive a restart.
"""

from __future__ import annotations

import json
from collections import Counter, OrderedDict
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from itertools import islice
from typing import Protocol

from starterbus.serve.metrics import Scalar

#: one buffered value: the metric's name, its value (None: null) and its acquisition time in ms
Value = tuple[str, Scalar | None, int]


@dataclass(frozen=True, slots=True)
class Bounds:
    """What the buffer may hold: records (would-be DDATA), bytes of stored records, and the age of the oldest."""

    messages: int = 1_000_000
    size: int = 100_000_000
    age: float = 86_400.0


@dataclass(frozen=True, slots=True)
class Record:
    id: int
    device: str
    values: tuple[Value, ...]


def encode_values(values: Sequence[Value]) -> str:
    """The stored form of a record's values (also its size for the size bound)."""
    return json.dumps(values, separators=(",", ":"), allow_nan=True)


def decode_values(text: str) -> tuple[Value, ...]:
    return tuple((str(n), v, int(t)) for n, v, t in json.loads(text))


class HistoryStore(Protocol):
    """The interface :class:`~starterbus.serve.session.EdgeSession` uses; counters count records."""

    bounds: Bounds
    buffered: int  # records ever stored
    delivered: int  # records removed once written
    dropped: int  # records dropped by a bound, or that could not be stored or published

    def __len__(self) -> int: ...

    def pending(self) -> Mapping[str, int]:
        """Device name -> records waiting."""
        ...

    def append(self, device: str, values: Sequence[Value], now_ms: int) -> None:
        """Store one record, then drop the oldest beyond the count and size bounds (the age: :meth:`expire`)."""
        ...

    def take(self, devices: Collection[str], limit: int) -> list[Record]:
        """Up to ``limit`` records of these devices, oldest first; they stay stored until removed."""
        ...

    def remove(self, ids: Sequence[int]) -> None:
        """Written: forget them (counted delivered)."""
        ...

    def discard(self, ids: Sequence[int]) -> None:
        """Cannot be published (unknown device or metrics): forget them (counted dropped)."""
        ...

    def expire(self, now_ms: int) -> None:
        """Drop (and count) the records older than the age bound."""
        ...

    def close(self) -> None: ...


class MemoryStore:
    """The buffer in memory: lost with the process (``store.SqliteStore`` survives it)."""

    def __init__(self, bounds: Bounds | None = None) -> None:
        self.bounds = bounds or Bounds()
        self.buffered = self.delivered = self.dropped = 0
        self._records: OrderedDict[int, tuple[Record, int, int]] = OrderedDict()  # id -> (record, oldest ms, size)
        self._pending: Counter[str] = Counter()
        self._size = 0
        self._next_id = 1

    def __len__(self) -> int:
        return len(self._records)

    def pending(self) -> Mapping[str, int]:
        return self._pending

    def append(self, device: str, values: Sequence[Value], now_ms: int) -> None:
        size = len(encode_values(values))
        record = Record(self._next_id, device, tuple(values))
        self._next_id += 1
        self._records[record.id] = (record, min((t for _, _, t in values), default=now_ms), size)
        self._pending[device] += 1
        self._size += size
        self.buffered += 1
        while len(self._records) > self.bounds.messages or self._size > self.bounds.size:
            self._pop_oldest()

    def _pop_oldest(self) -> None:
        _, (record, _, size) = self._records.popitem(last=False)
        self._forget(record, size)
        self.dropped += 1

    def _forget(self, record: Record, size: int) -> None:
        self._size -= size
        self._pending[record.device] -= 1
        if not self._pending[record.device]:
            del self._pending[record.device]

    def take(self, devices: Collection[str], limit: int) -> list[Record]:
        return list(islice((r for r, _, _ in self._records.values() if r.device in devices), limit))

    def _remove(self, ids: Sequence[int]) -> int:
        removed = 0
        for i in ids:
            entry = self._records.pop(i, None)
            if entry is not None:
                self._forget(entry[0], entry[2])
                removed += 1
        return removed

    def remove(self, ids: Sequence[int]) -> None:
        self.delivered += self._remove(ids)

    def discard(self, ids: Sequence[int]) -> None:
        self.dropped += self._remove(ids)

    def expire(self, now_ms: int) -> None:
        oldest = now_ms - int(self.bounds.age * 1000)
        while self._records and next(iter(self._records.values()))[1] < oldest:
            self._pop_oldest()

    def close(self) -> None:
        pass
