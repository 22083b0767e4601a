"""Pages of the SQLite history (:class:`~starterbus.ops.history.HistoryStore`) for OPC UA HistoryRead.

A read's domain follows OPC 10000-11 (6.5.3): of StartTime, EndTime and NumValuesPerNode at least two are given;
an EndTime before the StartTime, or an EndTime alone, reads backwards (latest first). Rows are taken in the order
(time, id), so rows of the same time keep the order they were written in. A page ends after the row it returned
last; the continuation point carries that row's (time, id) exactly, so the next page starts right after it:
nothing lost, nothing repeated, however many rows share one timestamp. It also carries what is left of a
one-ended read's NumValuesPerNode, and a checksum of the node and the request it belongs to (another request's
point is refused, BadContinuationPointInvalid). The server keeps no state: a point never expires.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any

from starterbus.ops.history import ALL_DEVICES, EVENT_COLUMNS, SAMPLE_COLUMNS, HistoryStore

#: a row whose SourceTimestamp (microseconds) lies in the range is in it: row times are floats in seconds
_EDGE = 0.5e-6
_MAGIC = b"SBH1"
_POINT = struct.Struct(">4sdqII")  # magic, time, row id, remaining (one-ended reads), checksum of the request
_SCAN = 500  # rows fetched at a time while a filter drops some


class InvalidRange(ValueError):
    """Fewer than two of StartTime, EndTime and NumValuesPerNode are given."""


class InvalidContinuation(ValueError):
    """A continuation point this server did not give for this node and this request."""


@dataclass(frozen=True, slots=True)
class Domain:
    """Seconds since the epoch; ``low``/``high`` None: open on that side. ``total``: the values wanted in all
    (one-ended reads; 0: no limit, pages of ``per_page``)."""

    low: float | None
    high: float | None
    reverse: bool
    total: int
    per_page: int


@dataclass(frozen=True, slots=True)
class Position:
    time: float
    row: int
    remaining: int  # one-ended reads: values still wanted after this page (0 with total 0)


def _given(moment: datetime | None) -> float | None:
    """The time in seconds, or None for "not specified" (DateTime.MinValue: asyncua sends 1601-01-01)."""
    if moment is None or moment.year <= 1601:
        return None
    if moment.tzinfo is None:  # asyncua decodes UtcTime without a zone
        moment = moment.replace(tzinfo=timezone.utc)
    return moment.timestamp()


def domain(start: datetime | None, end: datetime | None, count: int, page_max: int) -> Domain:
    """The rows a ReadRawModifiedDetails or ReadEventDetails asks for (OPC 10000-11 6.5.3.2)."""
    first, last = _given(start), _given(end)
    if first is not None and last is not None:
        page = min(count, page_max) if count else page_max
        return Domain(min(first, last), max(first, last), last < first, 0, page)
    if count <= 0 or (first is None and last is None):
        raise InvalidRange("give two of StartTime, EndTime and NumValuesPerNode")
    if first is not None:
        return Domain(first, None, False, count, min(count, page_max))
    return Domain(None, last, True, count, min(count, page_max))


def scope(kind: str, node: str, start: datetime | None, end: datetime | None, count: int) -> int:
    """The checksum binding a continuation point to its node and request."""
    return zlib.crc32(f"{kind}|{node}|{_given(start)}|{_given(end)}|{count}".encode())


def encode(position: Position, checksum: int) -> bytes:
    return _POINT.pack(_MAGIC, position.time, position.row, position.remaining, checksum)


def decode(point: bytes, checksum: int) -> Position:
    try:
        magic, time_, row, remaining, check = _POINT.unpack(point)
    except struct.error:
        raise InvalidContinuation(f"{len(point)} bytes") from None
    if magic != _MAGIC or check != checksum:
        raise InvalidContinuation("not given for this node and request")
    return Position(time_, row, remaining)


def page(
    store: HistoryStore,
    table: str,
    device: str | None,
    span: Domain,
    after: Position | None,
    accept: Callable[[dict[str, Any]], bool] = lambda row: True,
) -> tuple[list[dict[str, Any]], Position | None]:
    """One page of ``samples`` or ``events`` rows (of ``device``; events: with those about every device; None:
    every device) after ``after``, and where the next page starts (None: nothing more). ``accept`` filters
    rows (an event filter); rows it drops are skipped, never returned nor counted."""
    limit = span.per_page
    remaining = span.total
    if after is not None and span.total:
        remaining = after.remaining
        limit = min(limit, remaining)
    if span.total and remaining <= 0:
        return [], None
    columns = SAMPLE_COLUMNS if table == "samples" else EVENT_COLUMNS
    out: list[dict[str, Any]] = []
    cursor = (after.time, after.row) if after is not None else None
    while True:
        rows = _rows(store, table, columns, device, span, cursor, _SCAN)
        for row in rows:
            cursor = (row["time"], row["id"])
            if not accept(row):
                continue
            if len(out) == limit:  # one more exists: the page is full and another follows
                last = out[-1]
                left = remaining - len(out) if span.total else 0
                if span.total and left <= 0:
                    return out, None
                return out, Position(last["time"], last["id"], left)
            out.append(row)
        if len(rows) < _SCAN:
            return out, None


def _rows(
    store: HistoryStore,
    table: str,
    columns: Sequence[str],
    device: str | None,
    span: Domain,
    after: tuple[float, int] | None,
    limit: int,
) -> list[dict[str, Any]]:
    clauses: list[str] = []
    params: list[Any] = []
    if device is not None:
        if table == "events":
            clauses.append("device IN (?, ?)")
            params += [device, ALL_DEVICES]
        else:
            clauses.append("device = ?")
            params.append(device)
    if span.low is not None:
        clauses.append("time >= ?")
        params.append(span.low - _EDGE)
    if span.high is not None:
        clauses.append("time <= ?")
        params.append(span.high + _EDGE)
    if after is not None:
        clauses.append("(time < ? OR (time = ? AND id < ?))" if span.reverse else "(time > ? OR (time = ? AND id > ?))")
        params += [after[0], after[0], after[1]]
    where = " WHERE " + " AND ".join(clauses) if clauses else ""
    order = "time DESC, id DESC" if span.reverse else "time, id"
    names = ", ".join(f'"{c}"' for c in columns)
    sql = f"SELECT {names} FROM {table}{where} ORDER BY {order} LIMIT {int(limit)}"
    with store.lock:
        fetched = store.conn.execute(sql, params).fetchall()
    return [dict(zip(columns, r, strict=True)) for r in fetched]


def last_sample_before(store: HistoryStore, device: str, moment: float) -> dict[str, Any] | None:
    """The device's last sample before ``moment`` that answered without a fault (the currents before a trip)."""
    names = ", ".join(f'"{c}"' for c in SAMPLE_COLUMNS)
    sql = (
        f"SELECT {names} FROM samples WHERE device = ? AND time < ? AND online = 1 AND state IS NOT NULL"
        " AND state != 'fault' ORDER BY time DESC, id DESC LIMIT 1"
    )
    with store.lock:
        found = store.conn.execute(sql, (device, moment)).fetchone()
    return dict(zip(SAMPLE_COLUMNS, found, strict=True)) if found is not None else None
