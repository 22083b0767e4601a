"""The history database: samples and events in SQLite (WAL), queried by ``starterbus history`` and ``plot``.

SQLite in WAL mode with ``synchronous=NORMAL``: every sample is its own transaction, so a writer that
crashes or is killed loses at most the sample it was writing and never corrupts the file (a later open
replays or discards the WAL). Retention keeps the samples younger than ``max_age`` and the database under
``max_bytes`` (oldest samples first; deleted pages are reused, so the file stops growing there).

Tables::

    samples(id, time, device, model, online, state, fault_code, current_a, current_b, current_c, "values", error)
    events(id, time, device, kind, code, text, detail)   kind: state | fault | offline | online | write |
                                                         command | start | gap (device "*": every device)
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from starterbus.core.errors import ConfigurationError

SCHEMA = """
CREATE TABLE IF NOT EXISTS samples (
    id INTEGER PRIMARY KEY,
    time REAL NOT NULL,
    device TEXT NOT NULL,
    model TEXT NOT NULL DEFAULT '',
    online INTEGER NOT NULL,
    state TEXT,
    fault_code INTEGER,
    current_a REAL,
    current_b REAL,
    current_c REAL,
    "values" TEXT NOT NULL DEFAULT '{}',
    error TEXT
);
CREATE INDEX IF NOT EXISTS samples_device_time ON samples (device, time);
CREATE INDEX IF NOT EXISTS samples_time ON samples (time);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY,
    time REAL NOT NULL,
    device TEXT NOT NULL,
    kind TEXT NOT NULL,
    code INTEGER,
    text TEXT NOT NULL DEFAULT '',
    detail TEXT NOT NULL DEFAULT '{}'
);
CREATE INDEX IF NOT EXISTS events_device_time ON events (device, time);
"""

SAMPLE_COLUMNS = (
    "id", "time", "device", "model", "online", "state", "fault_code", "current_a", "current_b", "current_c",
    "values", "error",
)  # fmt: skip
EVENT_COLUMNS = ("id", "time", "device", "kind", "code", "text", "detail")
#: the device name of events about every device (a gap in the recording)
ALL_DEVICES = "*"
#: the first bytes of every SQLite 3 database file
SQLITE_MAGIC = b"SQLite format 3\x00"


@dataclass(frozen=True, slots=True)
class Retention:
    """Keep samples younger than ``max_age`` seconds and the database under ``max_bytes`` (None: no limit)."""

    max_age: float | None = None
    max_bytes: int | None = None


class HistoryStore:
    """One SQLite history file. Thread-safe (one connection behind a lock)."""

    def __init__(self, path: str | Path, *, create: bool = True, busy_timeout: float = 10.0) -> None:
        """``busy_timeout``: how long a write waits for another connection's lock before it fails."""
        self.path = Path(path)
        if not create and not self.path.exists():
            raise ConfigurationError(f"{self.path}: no such history database")
        try:
            self.conn = sqlite3.connect(
                str(self.path), check_same_thread=False, isolation_level=None, timeout=busy_timeout
            )
        except sqlite3.Error as exc:
            raise ConfigurationError(f"{self.path}: cannot open: {exc}") from exc
        try:
            self.conn.execute("PRAGMA journal_mode=WAL")
            self.conn.execute("PRAGMA synchronous=NORMAL")
            if create:
                self.conn.executescript(SCHEMA)
            else:
                self.conn.execute("SELECT 1 FROM samples LIMIT 1")
        except sqlite3.DatabaseError as exc:
            self.conn.close()
            raise ConfigurationError(f"{self.path}: not a starterbus history database ({exc})") from exc
        self.lock = threading.Lock()

    def close(self) -> None:
        with self.lock:
            self.conn.close()

    def __enter__(self) -> HistoryStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- writing ------------------------------------------------------------------------------------------

    def add_sample(self, row: Mapping[str, Any]) -> None:
        cols = [c for c in SAMPLE_COLUMNS if c != "id" and c in row]
        values = [json.dumps(row[c], ensure_ascii=False) if c == "values" else row[c] for c in cols]
        sql = f"INSERT INTO samples ({', '.join(_q(c) for c in cols)}) VALUES ({', '.join('?' * len(cols))})"
        with self.lock:
            self.conn.execute(sql, values)

    def add_batch(self, samples: Sequence[Mapping[str, Any]], events: Sequence[Mapping[str, Any]]) -> None:
        """Sample rows and event rows (``time, device, kind, text``, ``code``, ``detail``) in one transaction:
        all written, or none (the error raised)."""
        with self.lock:
            self.conn.execute("BEGIN IMMEDIATE")
            try:
                for row in samples:
                    cols = [c for c in SAMPLE_COLUMNS if c != "id" and c in row]
                    values = [json.dumps(row[c], ensure_ascii=False) if c == "values" else row[c] for c in cols]
                    self.conn.execute(
                        f"INSERT INTO samples ({', '.join(_q(c) for c in cols)}) VALUES ({', '.join('?' * len(cols))})",
                        values,
                    )
                for ev in events:
                    detail = json.dumps(dict(ev.get("detail") or {}), ensure_ascii=False, default=str)
                    self.conn.execute(
                        "INSERT INTO events (time, device, kind, code, text, detail) VALUES (?, ?, ?, ?, ?, ?)",
                        (ev["time"], ev["device"], ev["kind"], ev.get("code"), ev.get("text", ""), detail),
                    )
                self.conn.execute("COMMIT")
            except BaseException:
                if self.conn.in_transaction:
                    try:
                        self.conn.execute("ROLLBACK")
                    except sqlite3.Error:  # the disk failing again: SQLite rolls back when it can
                        pass
                raise

    def checkpoint(self) -> None:
        """Copy the write-ahead log into the database and empty it: on a full disk the log's older copies of the
        same pages give their space back (errors are the caller's)."""
        with self.lock:
            self.conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")

    def add_event(
        self,
        time_: float,
        device: str,
        kind: str,
        text: str,
        *,
        code: int | None = None,
        detail: Mapping[str, Any] | None = None,
    ) -> int:
        with self.lock:
            cur = self.conn.execute(
                "INSERT INTO events (time, device, kind, code, text, detail) VALUES (?, ?, ?, ?, ?, ?)",
                (time_, device, kind, code, text, json.dumps(dict(detail or {}), ensure_ascii=False, default=str)),
            )
            return int(cur.lastrowid or 0)

    def prune(self, retention: Retention, now: float | None = None) -> int:
        """Apply the retention; returns the number of samples deleted."""
        deleted = 0
        with self.lock:
            if retention.max_age is not None:
                cutoff = (time.time() if now is None else now) - retention.max_age
                deleted += self.conn.execute("DELETE FROM samples WHERE time < ?", (cutoff,)).rowcount
                self.conn.execute("DELETE FROM events WHERE time < ?", (cutoff,))
            if retention.max_bytes is not None:
                while self._used_bytes() > retention.max_bytes:
                    count = self.conn.execute("SELECT COUNT(*) FROM samples").fetchone()[0]
                    if count == 0:
                        break
                    batch = max(1, count // 10)
                    deleted += self.conn.execute(
                        "DELETE FROM samples WHERE id IN (SELECT id FROM samples ORDER BY time LIMIT ?)", (batch,)
                    ).rowcount
        return deleted

    def _used_bytes(self) -> int:
        pages = self.conn.execute("PRAGMA page_count").fetchone()[0]
        free = self.conn.execute("PRAGMA freelist_count").fetchone()[0]
        size = self.conn.execute("PRAGMA page_size").fetchone()[0]
        return int((pages - free) * size)

    # -- reading ------------------------------------------------------------------------------------------

    def samples(
        self,
        *,
        device: str | None = None,
        since: float | None = None,
        until: float | None = None,
        limit: int | None = None,
    ) -> list[dict[str, Any]]:
        where, params = _filters(device, since, until)
        sql = f"SELECT {', '.join(_q(c) for c in SAMPLE_COLUMNS)} FROM samples{where}"
        if limit is None:
            sql += " ORDER BY time, id"
        else:  # the last N, in time order
            sql = f"SELECT * FROM ({sql} ORDER BY time DESC, id DESC LIMIT {int(limit)}) ORDER BY time, id"
        with self.lock:
            rows = self.conn.execute(sql, params).fetchall()
        out = [dict(zip(SAMPLE_COLUMNS, r, strict=True)) for r in rows]
        for row in out:
            row["values"] = json.loads(row["values"] or "{}")
            row["online"] = bool(row["online"])
        return out

    def events(
        self,
        *,
        device: str | None = None,
        since: float | None = None,
        until: float | None = None,
        kind: str | None = None,
        after: int | None = None,
        limit: int | None = None,
    ) -> list[dict[str, Any]]:
        """In time order; ``after``: only those written after event id ``after`` (ids grow as events are
        written, whatever their time); ``limit``: the last ``limit`` of them."""
        where, params = _filters(device, since, until)
        if kind is not None:
            where += (" AND" if where else " WHERE") + " kind = ?"
            params.append(kind)
        if after is not None:
            where += (" AND" if where else " WHERE") + " id > ?"
            params.append(after)
        sql = f"SELECT {', '.join(EVENT_COLUMNS)} FROM events{where}"
        if limit is None:
            sql += " ORDER BY time, id"
        else:
            sql = f"SELECT * FROM ({sql} ORDER BY time DESC, id DESC LIMIT {int(limit)}) ORDER BY time, id"
        with self.lock:
            rows = self.conn.execute(sql, params).fetchall()
        out = [dict(zip(EVENT_COLUMNS, r, strict=True)) for r in rows]
        for row in out:
            row["detail"] = json.loads(row["detail"] or "{}")
        return out

    def devices(self) -> list[str]:
        """Every device name with a sample or an event, sorted."""
        with self.lock:
            rows = self.conn.execute("SELECT device FROM samples UNION SELECT device FROM events ORDER BY 1").fetchall()
        return [r[0] for r in rows if r[0] != ALL_DEVICES]

    def event(self, event_id: int) -> dict[str, Any]:
        with self.lock:
            row = self.conn.execute(
                f"SELECT {', '.join(EVENT_COLUMNS)} FROM events WHERE id = ?", (event_id,)
            ).fetchone()
        if row is None:
            raise ConfigurationError(f"{self.path}: no event {event_id} (`starterbus history DB --events` lists them)")
        out = dict(zip(EVENT_COLUMNS, row, strict=True))
        out["detail"] = json.loads(out["detail"] or "{}")
        return out


def _q(column: str) -> str:
    return f'"{column}"'


def _filters(device: str | None, since: float | None, until: float | None) -> tuple[str, list[Any]]:
    clauses: list[str] = []
    params: list[Any] = []
    if device is not None:  # with the events about every device (a gap in the recording)
        clauses.append("device IN (?, ?)")
        params += [device, ALL_DEVICES]
    if since is not None:
        clauses.append("time >= ?")
        params.append(since)
    if until is not None:
        clauses.append("time <= ?")
        params.append(until)
    return (" WHERE " + " AND ".join(clauses) if clauses else ""), params
