"""The store-and-forward buffer on disk: SQLite beside the state file, so that what was buffered while the broker
was away survives ``serve`` being stopped or killed, and goes out after the births of the next session.

One row per would-be DDATA, committed as it is stored: WAL with ``synchronous=NORMAL``, so a committed record
survives the process being killed (``kill -9``); a power cut may lose the last commits, never the file. The
counters (buffered, delivered, dropped) are kept in the same file and commit with the rows they count.

A file that is not a database (or fails SQLite's quick check) is moved aside, its new name logged, and a new one
started. A failure while running (disk full, I/O error) never stops the edge node: the record is dropped and
counted, the failure logged once until a write succeeds again.
"""

from __future__ import annotations

import logging
import os
import sqlite3
import time
from collections import Counter
from collections.abc import Callable, Collection, Mapping, Sequence
from pathlib import Path

from starterbus.core.errors import ConfigurationError
from starterbus.serve.history import Bounds, Record, Value, decode_values, encode_values

log = logging.getLogger("starterbus.serve")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS history (
    id INTEGER PRIMARY KEY, device TEXT NOT NULL, ts INTEGER NOT NULL, size INTEGER NOT NULL, ddata TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS history_ts ON history (ts);
CREATE TABLE IF NOT EXISTS counters (
    one INTEGER PRIMARY KEY CHECK (one = 1), buffered INTEGER NOT NULL, delivered INTEGER NOT NULL,
    dropped INTEGER NOT NULL
);
INSERT OR IGNORE INTO counters VALUES (1, 0, 0, 0);
"""


def default_buffer_file(state_file: Path) -> Path:
    """Beside the state file: ``serve-G-N.json`` -> ``serve-G-N.buffer.db``."""
    return state_file.with_name(f"{state_file.stem}.buffer.db")


def _connect(path: Path) -> sqlite3.Connection:
    db = sqlite3.connect(path, isolation_level=None, check_same_thread=False)  # used by one thread at a time
    try:
        db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=NORMAL")
        if db.execute("PRAGMA quick_check").fetchone()[0] != "ok":
            raise sqlite3.DatabaseError("quick_check failed")
        db.executescript(_SCHEMA)
    except BaseException:
        db.close()
        raise
    return db


class SqliteStore:
    """A :class:`~starterbus.serve.history.HistoryStore` in an SQLite file (opened by :meth:`open`)."""

    def __init__(self, db: sqlite3.Connection, path: Path, bounds: Bounds) -> None:
        self.db = db
        self.path = path
        self.bounds = bounds
        self.failing: str | None = None  # the last write failure, until a write succeeds again
        row = db.execute("SELECT buffered, delivered, dropped FROM counters").fetchone()
        self.buffered, self.delivered, self.dropped = (int(v) for v in row)
        self._pending: Counter[str] = Counter()
        self._count = self._size = 0
        self._load_rows()

    @classmethod
    def open(cls, path: Path, bounds: Bounds | None = None) -> SqliteStore:
        """Open (or create) the buffer file; a corrupt one is moved aside (its new name logged)."""
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigurationError(f"buffer file {path}: {exc.strerror}") from None
        try:
            db = _connect(path)
        except sqlite3.DatabaseError as exc:
            if isinstance(exc, sqlite3.OperationalError) and not path.exists():
                raise ConfigurationError(f"buffer file {path}: {exc}") from None
            aside = path.with_name(f"{path.name}.corrupt-{time.strftime('%Y%m%dT%H%M%S')}")
            for suffix in ("", "-wal", "-shm"):
                if Path(f"{path}{suffix}").exists():
                    os.replace(f"{path}{suffix}", f"{aside}{suffix}")
            log.warning("buffer file %s unreadable (%s): moved aside to %s, starting a new one", path, exc, aside)
            try:
                db = _connect(path)
            except sqlite3.Error as again:
                raise ConfigurationError(f"buffer file {path}: {again}") from None
        return cls(db, path, bounds or Bounds())

    # -- reading ------------------------------------------------------------------------------------------

    def __len__(self) -> int:
        return self._count

    @property
    def size(self) -> int:
        """Bytes of stored records (what ``Bounds.size`` bounds; the file is larger, see docs/serve.md)."""
        return self._size

    def pending(self) -> Mapping[str, int]:
        return self._pending

    def take(self, devices: Collection[str], limit: int) -> list[Record]:
        names = [d for d in devices if self._pending.get(d)]
        if not names:
            return []
        query = "SELECT id, device, ddata FROM history"
        params: list[object] = [limit]
        if len(names) < len(self._pending):
            query += f" WHERE device IN ({','.join('?' * len(names))})"
            params = [*names, limit]
        try:
            rows = self.db.execute(query + " ORDER BY id LIMIT ?", params)
            return [Record(int(i), str(d), decode_values(text)) for i, d, text in rows]
        except (sqlite3.Error, ValueError, TypeError) as exc:
            self._failed("read", exc)
            return []

    # -- writing ------------------------------------------------------------------------------------------

    def _failed(self, what: str, exc: Exception) -> None:
        try:
            if self.db.in_transaction:
                self.db.execute("ROLLBACK")
        except sqlite3.Error:
            pass
        text = f"{type(exc).__name__}: {exc}"
        if self.failing != text:
            log.warning("buffer file %s: %s failed (%s)", self.path, what, text)
        self.failing = text

    def _load_rows(self) -> None:
        self._pending = Counter(dict(self.db.execute("SELECT device, count(*) FROM history GROUP BY device")))
        self._count = sum(self._pending.values())
        self._size = int(self.db.execute("SELECT coalesce(sum(size), 0) FROM history").fetchone()[0])

    def _commit(self, what: str, work: Callable[[], None]) -> bool:
        """``work`` and the counters in one transaction; on failure nothing of it is kept, in the file or here."""
        counters = (self.buffered, self.delivered, self.dropped)
        try:
            self.db.execute("BEGIN IMMEDIATE")
            work()
            self.db.execute(
                "UPDATE counters SET buffered = ?, delivered = ?, dropped = ?",
                (self.buffered, self.delivered, self.dropped),
            )
            self.db.execute("COMMIT")
        except sqlite3.Error as exc:
            self.buffered, self.delivered, self.dropped = counters
            self._failed(what, exc)
            try:
                self._load_rows()  # what the file holds after the rollback
            except sqlite3.Error:
                pass
            return False
        if self.failing is not None:
            log.warning("buffer file %s: writing again", self.path)
            self.failing = None
        return True

    def _delete(self, rows: Sequence[tuple[int, str, int]]) -> None:
        self.db.executemany("DELETE FROM history WHERE id = ?", ((i,) for i, _, _ in rows))
        for _, device, size in rows:
            self._count -= 1
            self._size -= size
            self._pending[device] -= 1
            if not self._pending[device]:
                del self._pending[device]

    def append(self, device: str, values: Sequence[Value], now_ms: int) -> None:
        text = encode_values(values)
        oldest = min((t for _, _, t in values), default=now_ms)

        def insert() -> None:
            self.db.execute(
                "INSERT INTO history (device, ts, size, ddata) VALUES (?, ?, ?, ?)", (device, oldest, len(text), text)
            )
            self.buffered += 1
            self._count += 1
            self._size += len(text)
            self._pending[device] += 1
            self._drop_beyond_bounds()

        if not self._commit("store", insert):
            self.dropped += 1  # not stored: counted here, saved with the next commit that succeeds

    def _drop_beyond_bounds(self) -> None:
        bounds = self.bounds
        while self._count > bounds.messages or self._size > bounds.size:
            count, size = self._count, self._size
            batch: list[tuple[int, str, int]] = []
            for i, device, row_size in self.db.execute("SELECT id, device, size FROM history ORDER BY id LIMIT 64"):
                if count <= bounds.messages and size <= bounds.size:
                    break
                batch.append((int(i), str(device), int(row_size)))
                count, size = count - 1, size - int(row_size)
            self._delete(batch)
            self.dropped += len(batch)

    def remove(self, ids: Sequence[int]) -> None:
        self._forget(ids, delivered=True)

    def discard(self, ids: Sequence[int]) -> None:
        self._forget(ids, delivered=False)

    def _forget(self, ids: Sequence[int], *, delivered: bool) -> None:
        if not ids:
            return

        def delete() -> None:
            rows: list[tuple[int, str, int]] = []
            for start in range(0, len(ids), 500):
                chunk = ids[start : start + 500]
                marks = ",".join("?" * len(chunk))
                rows += self.db.execute(f"SELECT id, device, size FROM history WHERE id IN ({marks})", chunk)
            self._delete(rows)
            if delivered:
                self.delivered += len(rows)
            else:
                self.dropped += len(rows)

        self._commit("remove", delete)

    def expire(self, now_ms: int) -> None:
        if not self._count:
            return
        oldest = now_ms - int(self.bounds.age * 1000)

        def delete() -> None:
            rows = self.db.execute("SELECT id, device, size FROM history WHERE ts < ?", (oldest,)).fetchall()
            self._delete(rows)
            self.dropped += len(rows)

        try:
            if self.db.execute("SELECT 1 FROM history WHERE ts < ? LIMIT 1", (oldest,)).fetchone() is None:
                return
        except sqlite3.Error as exc:
            self._failed("expire", exc)
            return
        self._commit("expire", delete)

    def close(self) -> None:
        try:
            self.db.close()
        except sqlite3.Error:
            pass
