"""The history's disk failing (issue 26, item 2): full, read-only, gone, locked, corrupted. Polling and the JSON
stream go on, the failure shows in the log, the ``--json`` stream and the counters, the rows wait in a bounded
backlog, and the gap is recorded once the history can be written again. The full and read-only cases run on a
real small file system: a 160 kB tmpfs mounted by the test (as root; skipped where mounting is not allowed)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.parser import text_string_to_metric_families

from starterbus.cli.main import main
from starterbus.core.supervision import Backoff, Supervisor
from starterbus.fleet.poller import Sample
from starterbus.ops.history import HistoryStore
from starterbus.ops.history_writer import HistoryWriter
from starterbus.ops.recorder import HistoryRecorder
from starterbus.ops.service_metrics import ServiceCollector
from starterbus.testing.conformance import wait_until

from .conftest import Line
from .test_history import FLEET, status

WAIT = 30.0


class Tmpfs:
    def __init__(self, where: Path) -> None:
        self.where = where

    def remount(self, options: str) -> None:
        subprocess.run(["mount", "-o", f"remount,{options}", str(self.where)], check=True, capture_output=True)

    def ballast(self, size: int) -> Path:
        """``size`` bytes taken by one file, while there is room (removing it gives the space back)."""
        ballast = self.where / "ballast"
        ballast.write_bytes(b"\0" * size)
        return ballast


@pytest.fixture
def tmpfs(tmp_path: Path) -> Iterator[Tmpfs]:
    where = tmp_path / "disk"
    where.mkdir()
    if shutil.which("mount") is None:
        pytest.skip("no mount command here")
    mount = ["mount", "-t", "tmpfs", "-o", "size=160k", "tmpfs", str(where)]
    done = subprocess.run(mount, check=False, capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root): {done.stderr.decode().strip()}")
    try:
        yield Tmpfs(where)
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False, capture_output=True)


def sample(n: int, online: bool = True) -> Sample:
    return Sample("m1", "b", "jjr5000", 1000.0 + n, online, status() if online else None, {}, None, 0)


class Poll:
    """``starterbus poll ... --json`` as a subprocess; its stdout lines collected as they come."""

    def __init__(self, *args: str) -> None:
        previous = signal.signal(signal.SIGINT, signal.default_int_handler)
        try:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "starterbus.cli.main", "poll", *args, "--json"],
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
        finally:
            signal.signal(signal.SIGINT, previous)
        self.lines: list[dict[str, Any]] = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.lines.append(json.loads(line))  # every line is JSON, events included

    def samples(self) -> int:
        return sum("device" in x for x in list(self.lines))

    def event(self, state: str) -> dict[str, Any] | None:
        return next((x for x in list(self.lines) if x.get("event") == "history" and x["state"] == state), None)

    def wait(self, what: Any, message: str = "") -> None:
        assert wait_until(what, WAIT), (message, self.lines[-5:], self.stop_now())

    def stop_now(self) -> str:
        self.process.kill()
        return self.process.communicate()[1]

    def terminate(self) -> tuple[int, str]:
        self.process.send_signal(signal.SIGTERM)
        _, err = self.process.communicate(timeout=WAIT)
        return self.process.returncode, err


def rows(db: Path, sql: str) -> list[tuple[Any, ...]]:
    with sqlite3.connect(db, timeout=5) as conn:
        return conn.execute(sql).fetchall()


def test_a_full_disk_stops_nothing_and_the_gap_is_recorded_once_space_returns(
    tmpfs: Tmpfs, line: Line, tmp_path: Path
) -> None:
    fleet, db = tmp_path / "fleet.toml", tmpfs.where / "h.db"
    fleet.write_text(FLEET.format(port=line.port), encoding="utf-8")
    ballast = tmpfs.ballast(48 * 1024)
    poll = Poll(str(fleet), "--record", str(db))  # two devices at 20 Hz fill the remaining 112 kB in seconds
    poll.wait(lambda: poll.event("failing") is not None, "the failure said in the JSON stream")
    failing = poll.event("failing")
    assert failing is not None and "full" in failing["error"] and failing["file"] == str(db)
    before = poll.samples()
    poll.wait(lambda: poll.samples() >= before + 20, "polling goes on while the disk is full")
    ballast.unlink()
    poll.wait(lambda: poll.event("recording") is not None, "recording again once space returns")
    code, err = poll.terminate()
    assert code == 0, err  # SIGTERM: a requested stop, after a clean shutdown
    assert "cannot write the history: database or disk is full" in err and "recording again" in err
    gaps = rows(db, "SELECT device, text, detail FROM events WHERE kind = 'gap' ORDER BY id")
    assert gaps and gaps[0][0] == "*" and "database or disk is full" in gaps[0][1]
    outage = json.loads(gaps[0][2])
    during = rows(db, f"SELECT COUNT(*) FROM samples WHERE time BETWEEN {outage['from']} AND {outage['to']}")
    assert during[0][0] >= 1, "samples taken while the disk was full were kept in memory and written after"
    assert rows(db, "PRAGMA integrity_check") == [("ok",)]


def test_a_read_only_file_system_then_writable_again_with_a_bounded_backlog(tmpfs: Tmpfs) -> None:
    tmpfs.remount("ro")
    db = tmpfs.where / "h.db"
    told: list[dict[str, Any]] = []
    recorder = HistoryRecorder(db, backlog=5, retry=0.02, on_event=told.append)
    writer = recorder.writer
    try:
        assert writer.failing_since is not None and "read-only" in str(writer.error)
        for n in range(20):
            recorder(sample(n))  # never waits for the disk
        assert writer.pending == 5 and writer.dropped_samples == 15
        tmpfs.remount("rw")
        assert wait_until(lambda: writer.failing_since is None and writer.pending == 0, WAIT), writer.error
    finally:
        recorder.close()
    assert [t["state"] for t in told] == ["failing", "recording"]
    assert told[1]["samples_dropped"] == 15
    with HistoryStore(db, create=False) as store:
        assert [s["time"] for s in store.samples()] == [1015.0, 1016.0, 1017.0, 1018.0, 1019.0], "the newest kept"
        (gap,) = store.events(kind="gap")
    assert "read-only" in gap["text"] and "15 samples and 0 events dropped" in gap["text"]
    assert gap["detail"]["first_dropped"] == 1000.0 and gap["detail"]["last_dropped"] == 1014.0


def corrupt(db: Path) -> bytes:
    """Every page but the first overwritten with random bytes; returns the file's digest."""
    size = db.stat().st_size
    with db.open("r+b") as f:
        for page in range(1, size // 4096):
            f.seek(page * 4096)
            f.write(os.urandom(4096))
    return hashlib.sha256(db.read_bytes()).digest()


def test_a_corrupted_history_is_moved_aside_and_a_new_one_started(line: Line, tmp_path: Path) -> None:
    fleet, db = tmp_path / "fleet.toml", tmp_path / "h.db"
    fleet.write_text(FLEET.format(port=line.port), encoding="utf-8")
    with HistoryStore(db) as store:
        for n in range(3000):
            store.add_sample({"time": float(n), "device": "conveyor", "online": 1, "values": {}})
    digest = corrupt(db)
    poll = Poll(str(fleet), "--record", str(db))
    poll.wait(lambda: poll.event("moved-aside") is not None, "moved aside")
    poll.wait(lambda: poll.event("recording") is not None and poll.samples() >= 10, "a new history")
    code, err = poll.terminate()
    assert code == 0, err
    moved = Path(str(poll.event("moved-aside")["moved_to"]))  # type: ignore[index]
    assert moved.parent == tmp_path and moved.name.startswith("h.db.corrupt-2") and len(moved.name) == 28
    assert f"moved aside to {moved}" in err
    assert hashlib.sha256(moved.read_bytes()).digest() == digest, "the corrupted file kept as it was"
    with HistoryStore(db, create=False) as store:
        assert store.conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        assert len(store.samples()) >= 10
        (gap,) = store.events(kind="gap")
    assert gap["detail"]["moved_aside"] == str(moved)


def test_a_vanished_directory_then_back(tmp_path: Path) -> None:
    where = tmp_path / "d"
    where.mkdir()
    recorder = HistoryRecorder(where / "h.db", retry=0.02)
    writer = recorder.writer
    try:
        recorder(sample(0))
        assert wait_until(lambda: writer.written_samples == 1, WAIT)
        shutil.rmtree(where)
        recorder(sample(1, online=False))
        assert wait_until(lambda: writer.failing_since is not None, WAIT)
        assert "is gone" in str(writer.error)
        where.mkdir()
        assert wait_until(lambda: writer.failing_since is None and writer.pending == 0, WAIT), writer.error
    finally:
        recorder.close()
    with HistoryStore(where / "h.db", create=False) as store:  # a new file, with what came meanwhile
        assert [(s["time"], s["online"]) for s in store.samples()] == [(1001.0, False)]
        assert sorted(e["kind"] for e in store.events()) == ["gap", "offline"]


def metrics(collector: ServiceCollector) -> dict[str, float]:
    registry = CollectorRegistry(auto_describe=False)
    registry.register(collector)
    text = generate_latest(registry).decode()
    return {
        s.name + "".join(f"{{{v}}}" for v in s.labels.values()): s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
    }


def test_a_locked_database_waits_and_loses_nothing_and_the_metrics_say_so(tmp_path: Path) -> None:
    db = tmp_path / "h.db"
    supervisor = Supervisor()
    writer = HistoryWriter(db, retry=0.02, busy_timeout=0.05, supervisor=supervisor)
    collector = ServiceCollector(supervisor, writer)
    try:
        other = sqlite3.connect(db, isolation_level=None)
        other.execute("BEGIN EXCLUSIVE")
        writer.add([{"time": 1.0, "device": "d", "online": 1}], [])
        assert wait_until(lambda: writer.failing_since is not None, WAIT)
        assert "locked" in str(writer.error) and writer.pending == 1
        seen = metrics(collector)
        assert seen["starterbus_history_writable"] == 0 and seen["starterbus_history_backlog"] == 1
        assert seen["starterbus_history_write_errors_total"] >= 1 and seen["starterbus_history_outages_total"] == 1
        other.execute("COMMIT")
        other.close()
        assert wait_until(lambda: writer.failing_since is None and writer.pending == 0, WAIT)
        seen = metrics(collector)
        assert seen["starterbus_history_writable"] == 1 and seen["starterbus_history_written_total{samples}"] == 1
        assert seen["starterbus_history_dropped_total{samples}"] == 0
    finally:
        writer.close()
    with HistoryStore(db, create=False) as store:
        assert len(store.samples()) == 1 and [e["kind"] for e in store.events()] == ["gap"]


def test_a_defect_in_the_writer_is_contained_and_the_rows_stay(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    original = HistoryStore.add_batch
    failed: list[int] = []

    def add_batch(self: HistoryStore, *args: Any) -> None:
        if not failed:
            failed.append(1)
            raise RuntimeError("a defect in the writer")
        original(self, *args)

    monkeypatch.setattr(HistoryStore, "add_batch", add_batch)
    supervisor = Supervisor(Backoff(first=0.01))
    writer = HistoryWriter(tmp_path / "h.db", supervisor=supervisor)
    try:
        writer.add([{"time": 1.0, "device": "d", "online": 1}], [])
        assert wait_until(lambda: writer.written_samples == 1, WAIT), "restarted, and the row written"
    finally:
        writer.close()
    assert supervisor.failures == {"history-writer": 1} and supervisor.failure is None


def test_a_file_that_is_not_sqlite_is_refused_and_left_alone(
    tmp_path: Path, line: Line, capsys: pytest.CaptureFixture[str]
) -> None:
    fleet = tmp_path / "fleet.toml"
    fleet.write_text(FLEET.format(port=line.port), encoding="utf-8")
    assert main(["poll", str(fleet), "--once", "--record", str(fleet)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"starterbus: error: {fleet}: not a SQLite database; refusing to record into it "
                   "(give a history database or a new file)"]  # fmt: skip
    assert fleet.read_text(encoding="utf-8") == FLEET.format(port=line.port)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fleet.toml"]


def test_close_says_what_could_not_be_written(tmpfs: Tmpfs, caplog: pytest.LogCaptureFixture) -> None:
    tmpfs.remount("ro")
    writer = HistoryWriter(tmpfs.where / "h.db", retry=0.02)
    writer.add([{"time": 1.0, "device": "d", "online": 1}], [])
    writer.close()
    assert not writer.thread.is_alive()
    assert any("not written at the end: 1 samples and 0 events" in r.getMessage() for r in caplog.records)
