"""Writing the history in a thread of its own, so that a failing disk never stops polling or publishing.

Rows wait in memory (bounded: ``backlog`` samples and as many events; the oldest beyond it are dropped and
counted) and are written in batches, one transaction each. When a write fails (disk full, a read-only or
vanished directory, a locked database), the failure is logged once, counted and told to ``on_event``; the
writer tries again every ``retry`` seconds, and once it can write again it records the gap as an event
(kind ``gap``, device ``*``: when, why, what was dropped) and goes on with the rows kept meanwhile. A corrupted
database is moved aside (``h.db.corrupt-20261126T143311``, with its ``-wal`` and ``-shm``) and a new one
started. A file that is not a SQLite database at all is never touched: recording into it is refused at the
start (and retried later if one appears there while running).
"""

from __future__ import annotations

import logging
import os
import sqlite3
import threading
import time
from collections import deque
from collections.abc import Callable
from itertools import islice
from pathlib import Path
from typing import Any

from starterbus.core.errors import ConfigurationError
from starterbus.core.supervision import Supervisor
from starterbus.core.timestamps import iso_time
from starterbus.ops.history import ALL_DEVICES, SQLITE_MAGIC, HistoryStore, Retention
from starterbus.ops.history_faults import Corrupt, file_system_view, is_corrupt, sqlite_error

log = logging.getLogger("starterbus.history")

#: samples kept in memory while the history cannot be written (as many events again)
DEFAULT_BACKLOG = 10_000
#: seconds between two attempts while the history cannot be written
DEFAULT_RETRY = 2.0
_BATCH = 1000  # rows of each table per transaction

Row = dict[str, Any]


class HistoryWriter:
    """Writes sample and event rows to a :class:`HistoryStore` at ``path`` from its own thread; see the module.

    :meth:`add` never waits for the disk. ``on_event(dict)`` hears ``{"event": "history", "state": "failing" |
    "recording" | "moved-aside", ...}`` (``poll --json`` prints them). The thread runs under ``supervisor``
    (contained: a bug in it is logged, counted and the thread restarted; the rows stay).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        retention: Retention | None = None,
        backlog: int = DEFAULT_BACKLOG,
        retry: float = DEFAULT_RETRY,
        prune_every: float = 60.0,
        busy_timeout: float = 5.0,
        supervisor: Supervisor | None = None,
        on_event: Callable[[dict[str, Any]], None] | None = None,
    ) -> None:
        if backlog < 1:
            raise ConfigurationError(f"history backlog {backlog}: keep at least 1 sample")
        self.path = Path(path)
        self.retention = retention or Retention()
        self.backlog = backlog
        self.retry = retry
        self.prune_every = prune_every
        self.busy_timeout = busy_timeout
        self._on_event = on_event
        self.store: HistoryStore | None = None
        self._identity: tuple[int, int] | None = None  # (device, inode) of the file open
        self._samples: deque[tuple[int, Row]] = deque()
        self._events: deque[tuple[int, Row]] = deque()
        self._seq = 0
        self._cond = threading.Condition()
        self._closing = threading.Event()
        self._next_attempt = 0.0
        self._last_prune = time.monotonic()
        # counters (read by metrics)
        self.written_samples = 0
        self.written_events = 0
        self.dropped_samples = 0
        self.dropped_events = 0
        self.write_errors = 0  # failed attempts
        self.outages = 0  # episodes of failing
        self.moved_aside: list[Path] = []
        # the current episode of failing
        self.failing_since: float | None = None  # wall-clock time of its first failure
        self.error: str | None = None
        self._episode: dict[str, Any] = {}
        self._refuse_foreign_file()
        if not self.path.parent.is_dir():
            raise ConfigurationError(f"{self.path}: no such directory {self.path.parent}")
        try:
            self._open()
        except (sqlite3.Error, ConfigurationError, OSError, Corrupt) as exc:
            self._failed(exc)  # polling starts anyway; the history follows once it can be written
        supervisor = supervisor or Supervisor()
        self.thread = supervisor.thread("history-writer", self._run, restart=True, until=self._closing)
        self.thread.start()

    @property
    def on_event(self) -> Callable[[dict[str, Any]], None] | None:
        return self._on_event

    @on_event.setter
    def on_event(self, listener: Callable[[dict[str, Any]], None] | None) -> None:
        """A listener set late hears at once that the history is failing, if it is (e.g. since the start)."""
        self._on_event = listener
        if listener is not None and self.failing_since is not None:
            self._tell({"state": "failing", "error": self.error})

    # -- the producers' side --------------------------------------------------------------------------------

    def add(self, samples: list[Row], events: list[Row]) -> None:
        """Queue rows for writing (events: ``time, device, kind, text`` and optional ``code``, ``detail``)."""
        with self._cond:
            for row in samples:
                self._seq += 1
                self._samples.append((self._seq, row))
            for ev in events:
                self._seq += 1
                self._events.append((self._seq, ev))
            while len(self._samples) > self.backlog:
                _, dropped = self._samples.popleft()
                self.dropped_samples += 1
                self._note_drop("samples", dropped.get("time"))
            while len(self._events) > self.backlog:
                _, dropped = self._events.popleft()
                self.dropped_events += 1
                self._note_drop("events", dropped.get("time"))
            self._cond.notify()

    def _note_drop(self, what: str, when: object) -> None:
        episode = self._episode
        episode[f"{what}_dropped"] = episode.get(f"{what}_dropped", 0) + 1
        if episode[f"{what}_dropped"] == 1:
            log.error(
                "%s: more than %d %s wait for the disk (%s): dropping the oldest, counted",
                self.path,
                self.backlog,
                what,
                self.error or "it is too slow",
            )
        if isinstance(when, (int, float)):
            episode.setdefault("first_dropped", when)
            episode["last_dropped"] = when

    @property
    def pending(self) -> int:
        """Rows waiting to be written."""
        with self._cond:
            return len(self._samples) + len(self._events)

    def close(self, timeout: float = 10.0) -> None:
        """Write what waits (one last try if the history is failing), stop the thread, close the file."""
        self._closing.set()
        with self._cond:
            self._cond.notify()
        self.thread.join(timeout)
        if not self.thread.is_alive():
            while self.pending and self._attempt():
                pass
        left_samples, left_events = len(self._samples), len(self._events)
        if left_samples or left_events:
            log.error(
                "%s: not written at the end: %d samples and %d events (%s)",
                self.path,
                left_samples,
                left_events,
                self.error or "the writer did not finish in time",
            )
        if not self.thread.is_alive():
            self._close_store()

    # -- the writer thread ----------------------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._closing.is_set():
                    now = time.monotonic()
                    waiting = bool(self._samples or self._events)
                    if waiting and now >= self._next_attempt:
                        break
                    if not waiting and self._prune_due(now):
                        break
                    timeout: float | None
                    if waiting:
                        timeout = self._next_attempt - now
                    else:
                        timeout = self._last_prune + self.prune_every - now if self._prunes() else None
                    self._cond.wait(timeout)
            if self._closing.is_set():
                while self.pending and self._attempt():  # what waits, while the disk takes it
                    pass
                return
            if self._attempt() and self._prune_due(time.monotonic()):
                self._prune()

    def _prunes(self) -> bool:
        return self.retention != Retention()

    def _prune_due(self, now: float) -> bool:
        return self._prunes() and self.failing_since is None and now - self._last_prune >= self.prune_every

    def _prune(self) -> None:
        self._last_prune = time.monotonic()
        try:
            self._ensure_open().prune(self.retention)
        except (sqlite3.Error, ConfigurationError, OSError, Corrupt) as exc:
            self._failed(exc)

    def _attempt(self) -> bool:
        """Write one batch of what waits (with the gap event after a failure); False if it failed."""
        with self._cond:
            samples = list(islice(self._samples, _BATCH))
            events = list(islice(self._events, _BATCH))
            gap = self._gap_event() if self.failing_since is not None else None
        try:
            store = self._ensure_open()
            store.add_batch([r for _, r in samples], [r for _, r in events] + ([gap] if gap is not None else []))
        except (sqlite3.Error, ConfigurationError, OSError, Corrupt) as exc:
            self._failed(exc)
            return False
        with self._cond:
            self._remove(self._samples, samples)
            self._remove(self._events, events)
        self.written_samples += len(samples)
        self.written_events += len(events)
        if gap is not None:
            self._recovered(gap)
        return True

    @staticmethod
    def _remove(queue: deque[tuple[int, Row]], written: list[tuple[int, Row]]) -> None:
        """Take the written rows out (some may have been dropped meanwhile: by their sequence numbers)."""
        if not written:
            return
        last = written[-1][0]
        while queue and queue[0][0] <= last:
            queue.popleft()

    # -- the file -------------------------------------------------------------------------------------------

    def _refuse_foreign_file(self) -> None:
        """A file that is not SQLite is somebody else's: never written into, never moved."""
        try:
            with self.path.open("rb") as f:
                head = f.read(len(SQLITE_MAGIC))
        except FileNotFoundError:
            return
        except OSError as exc:
            raise ConfigurationError(f"{self.path}: cannot read it: {exc.strerror or exc}") from None
        if head and head != SQLITE_MAGIC:
            raise ConfigurationError(
                f"{self.path}: not a SQLite database; refusing to record into it "
                "(give a history database or a new file)"
            )

    def _open(self) -> HistoryStore:
        self._refuse_foreign_file()
        try:
            store = HistoryStore(self.path, busy_timeout=self.busy_timeout)
        except ConfigurationError as exc:
            if is_corrupt(exc):
                raise Corrupt(str(exc.__cause__)) from exc
            raise
        st = os.stat(self.path)
        self.store, self._identity = store, (st.st_dev, st.st_ino)
        return store

    def _ensure_open(self) -> HistoryStore:
        """The store, reopened if the file open is no longer the one at ``path`` (deleted, its directory gone)."""
        store = self.store
        if store is not None:
            try:
                st = os.stat(self.path)
                same = (st.st_dev, st.st_ino) == self._identity
            except OSError:
                same = False
            if same:
                return store
            log.error("%s: the file open was removed or replaced; writing to %s again", self.path, self.path)
            self._close_store()
        return self._open()

    def _close_store(self) -> None:
        store, self.store, self._identity = self.store, None, None
        if store is not None:
            try:
                store.close()
            except sqlite3.Error:
                pass

    def _move_aside(self) -> Path:
        """The corrupted file (and its ``-wal``, ``-shm``) renamed ``NAME.corrupt-YYYYMMDDTHHMMSS``."""
        self._close_store()
        stamp = time.strftime("%Y%m%dT%H%M%S")
        target = self.path.with_name(f"{self.path.name}.corrupt-{stamp}")
        n = 1
        while target.exists():
            n += 1
            target = self.path.with_name(f"{self.path.name}.corrupt-{stamp}-{n}")
        os.replace(self.path, target)
        for suffix in ("-wal", "-shm"):
            side = Path(f"{self.path}{suffix}")
            if side.exists():
                os.replace(side, Path(f"{target}{suffix}"))
        self.moved_aside.append(target)
        return target

    # -- failing and recovering -----------------------------------------------------------------------------

    def _failed(self, exc: BaseException) -> None:
        error = sqlite_error(exc)
        text = str(error if error is not None else exc)
        if isinstance(exc, Corrupt) or is_corrupt(exc):
            self._corrupted(text)
            return
        view = file_system_view(self.path)
        reason = f"{text}: {view}" if view else text
        if "full" in text and self.store is not None:
            try:
                self.store.checkpoint()  # the log's older page copies freed: the next attempt may fit
            except sqlite3.Error:
                pass
        self.write_errors += 1
        self._next_attempt = time.monotonic() + self.retry
        if not self.path.exists():
            self._close_store()  # the file or its directory vanished: a new one once it can be made
        if self.failing_since is None:
            self.failing_since = time.time()
            self.outages += 1
        if reason != self.error:  # logged once per cause, not per attempt
            self.error = reason
            log.error(
                "%s: cannot write the history: %s; polling goes on, samples kept in memory: %d (at most %d), "
                "retrying every %g s",
                self.path,
                reason,
                len(self._samples),
                self.backlog,
                self.retry,
            )
            self._tell({"state": "failing", "error": reason})

    def _corrupted(self, text: str) -> None:
        try:
            target = self._move_aside()
        except OSError as exc:
            self._failed(OSError(f"corrupted ({text}), and it cannot be moved aside: {exc.strerror or exc}"))
            return
        if self.failing_since is None:
            self.failing_since = time.time()
            self.outages += 1
        self.error = f"corrupted ({text})"
        self._episode["moved_aside"] = str(target)
        self._next_attempt = 0.0  # a new file at once
        log.error("%s: corrupted (%s): moved aside to %s; a new one started", self.path, text, target)
        self._tell({"state": "moved-aside", "error": self.error, "moved_to": str(target)})

    def _gap_event(self) -> Row:
        since = self.failing_since or time.time()
        now = time.time()
        episode = dict(self._episode)
        samples, events = episode.get("samples_dropped", 0), episode.get("events_dropped", 0)
        lost = f"{samples} samples and {events} events dropped" if samples or events else "nothing dropped"
        text = f"history not written for {now - since:.1f} s: {self.error}; {lost}"
        if "moved_aside" in episode:
            text += f"; the corrupted file moved aside to {episode['moved_aside']}"
        detail: dict[str, Any] = {
            "from": since,
            "to": now,
            "error": self.error,
            "samples_dropped": samples,
            "events_dropped": events,
            **{k: episode[k] for k in ("first_dropped", "last_dropped", "moved_aside") if k in episode},
        }
        return {"time": since, "device": ALL_DEVICES, "kind": "gap", "text": text, "detail": detail}

    def _recovered(self, gap: Row) -> None:
        detail = gap["detail"]
        log.warning("%s: recording again: %s", self.path, gap["text"])
        with self._cond:
            self.failing_since, self.error, self._episode = None, None, {}
        self._tell(
            {
                "state": "recording",
                "gap_s": round(detail["to"] - detail["from"], 3),
                "samples_dropped": detail["samples_dropped"],
                "events_dropped": detail["events_dropped"],
            }
        )

    def _tell(self, what: dict[str, Any]) -> None:
        if self._on_event is not None:
            self._on_event({"event": "history", "file": str(self.path), "time": iso_time(), **what})
