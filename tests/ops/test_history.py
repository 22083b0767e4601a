"""History: ``poll --record`` writes samples and events; ``history`` reads them; a killed writer corrupts nothing."""

from __future__ import annotations

import json
import re
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from starterbus.cli.main import main
from starterbus.core.device import open_device
from starterbus.core.errors import ConfigurationError
from starterbus.core.model import Value
from starterbus.core.registry import get_profile
from starterbus.core.status import Status
from starterbus.fleet.poller import Sample
from starterbus.ops.history import HistoryStore, Retention
from starterbus.ops.recorder import HistoryRecorder, parse_keep
from starterbus.testing import wait_until

from .conftest import Line

WAIT = 15.0
ISO = r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}\+00:00"


def count(db: Path, sql: str) -> int:
    if not db.exists():
        return 0
    try:
        with sqlite3.connect(db, timeout=5) as conn:
            return int(conn.execute(sql).fetchone()[0])
    except sqlite3.OperationalError:  # the writer has not created the tables yet
        return 0


def spawn(args: list[str]) -> subprocess.Popen[bytes]:
    # a runner started in the background ignores SIGINT, and a child inherits that: give it the default handling
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return subprocess.Popen([sys.executable, *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    finally:
        signal.signal(signal.SIGINT, previous)


FLEET = """
[poll]
period = 0.05

[[bus]]
name = "l1"
url = "modbus-rtu://{port}?timeout=0.3"

  [[bus.device]]
  name = "conveyor"
  model = "jjr5000"
  address = 2
  parameters = ["current_limit", "motor_rated_current"]

  [[bus.device]]
  name = "crusher"
  model = "jjr8000"
  address = 5
  measurements = ["last_fault_code"]
"""


def test_a_fault_during_poll_record_is_an_event_with_its_text(
    line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fleet, db = tmp_path / "fleet.toml", tmp_path / "h.db"
    fleet.write_text(FLEET.format(port=line.port), encoding="utf-8")
    proc = spawn(["-m", "starterbus.cli.main", "poll", str(fleet), "--record", str(db), "--keep", "7d"])
    try:
        assert wait_until(lambda: count(db, "SELECT COUNT(DISTINCT device) FROM samples WHERE online = 1") == 2, WAIT)
        line.starters[2].params["ramp_time"] = 120  # 6 s of starting on the fast clock: the poll sees it, loaded or not
        line.starters[2].start()
        assert wait_until(
            lambda: count(db, "SELECT COUNT(*) FROM samples WHERE device = 'conveyor' AND current_a > 0") > 0, WAIT
        )
        line.starters[2].inject_fault(6)
        line.starters[5].inject_fault(8)
        assert wait_until(lambda: count(db, "SELECT COUNT(*) FROM events WHERE kind = 'fault'") == 2, WAIT)
        other = Line()  # the fleet holds its line: a guarded write to a device elsewhere, audited -> an event
        try:
            with open_device(other.url(5), "jjr8000") as dev:
                dev.write("ramp_time", 10)
        finally:
            other.sim.close()
        assert wait_until(lambda: count(db, "SELECT COUNT(*) FROM events WHERE kind = 'write'") == 1, WAIT)
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 130, proc.stderr.read() if proc.stderr else ""  # Ctrl-C: 130, cleanly
    assert main(["history", str(db), "--events"]) == 0
    out = capsys.readouterr().out
    rows = [ln.split(None, 4)[2:] for ln in out.splitlines()[2:]]
    assert ["conveyor", "fault", "6: motor overload"] in rows and ["crusher", "fault", "8: high-current trip"] in rows
    assert "ramp_time" in out and "starting" in out
    assert main(["history", str(db), "--events", "--kind", "fault", "--device", "conveyor", "--json"]) == 0
    (fault,) = json.loads(capsys.readouterr().out)["events"]
    assert fault["code"] == 6 and fault["text"] == "6: motor overload"
    assert any(c["a"] > 0 for c in fault["detail"]["currents_before"])  # the currents before the trip
    assert main(["history", str(db), "--device", "crusher", "--since", "1h", "--limit", "1", "--json"]) == 0
    (sample,) = json.loads(capsys.readouterr().out)["samples"]
    assert sample["values"]["last_fault_code"]["text"] == "8: high-current trip"
    assert main(["history", str(db), "--device", "conveyor", "--csv"]) == 0
    csv_lines = capsys.readouterr().out.splitlines()
    assert csv_lines[0].startswith("id,time,device") and len(csv_lines) > 2
    assert re.fullmatch(ISO, csv_lines[1].split(",")[1])  # the one time form of every JSON and file


WRITER = """
import sys, time
from starterbus.fleet.poller import Sample
from starterbus.ops.recorder import HistoryRecorder
rec = HistoryRecorder(sys.argv[1])
n = 0
while True:
    n += 1
    rec(Sample("d%d" % (n % 3), "bus", "jjr5000", time.time(), n % 50 != 0, None, {}, None if n % 50 else "gone", 0))
"""


def test_a_killed_writer_leaves_a_sound_database(tmp_path: Path) -> None:
    db = tmp_path / "h.db"
    proc = spawn(["-c", WRITER, str(db)])
    try:
        assert wait_until(lambda: count(db, "SELECT COUNT(*) FROM samples") >= 500, WAIT)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    with sqlite3.connect(db) as conn:
        assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert conn.execute("SELECT COUNT(*) FROM samples").fetchone()[0] >= 500
        assert conn.execute("SELECT COUNT(*) FROM events WHERE kind = 'offline'").fetchone()[0] >= 1
    with HistoryStore(db, create=False) as store:  # and it still takes writes
        store.add_event(time.time(), "d1", "state", "after the crash")


def status(*, running: bool = False, fault: int | None = None, amps: float = 0.0) -> Status:
    point = get_profile("jjr5000").points["phase_a_current"]
    currents = {x: Value.from_raw(point, round(amps * 10), 0.1) for x in "abc"}
    text = get_profile("jjr5000").faults.text(fault) if fault else None
    return Status(fault is not None, fault, text, False, running, False, ready=True, currents=currents)


def test_events_from_a_sample_stream(tmp_path: Path) -> None:
    db = tmp_path / "h.db"
    stream = [
        (True, status()),
        (True, status(running=True, amps=300)),
        (True, status(running=True, amps=310)),
        (True, status(fault=7)),
        (False, None),
        (False, None),
        (True, status(fault=7)),
    ]
    with HistoryRecorder(db) as rec:
        for n, (online, st) in enumerate(stream):
            rec(Sample("m1", "b", "jjr5000", 1000.0 + n, online, st, {}, None if online else "no answer", 0))
    with HistoryStore(db, create=False) as store:
        events = [(e["kind"], e["text"]) for e in store.events()]
        fault = store.events(kind="fault")[0]
    assert events == [
        ("state", "ready -> running"),
        ("state", "running -> fault"),
        ("fault", "7: motor locked rotor"),
        ("offline", "no answer"),
        ("online", "answering again after 2.0 s"),
    ]
    assert [c["a"] for c in fault["detail"]["currents_before"]] == [0.0, 300.0, 310.0]


def test_retention_by_age_and_size(tmp_path: Path) -> None:
    with HistoryStore(tmp_path / "h.db") as store:
        for n in range(2000):
            store.add_sample({"time": float(n), "device": "d", "online": 1, "values": {"x": {"text": "y" * 50}}})
        assert store.prune(Retention(max_age=1000), now=2000.0) == 1000
        assert store.samples()[0]["time"] == 1000.0
        store.prune(Retention(max_bytes=40_000))
        kept = store.samples()
        assert 0 < len(kept) < 1000 and kept[-1]["time"] == 1999.0  # the newest stay
    assert parse_keep(["30d", "500MB"]) == Retention(30 * 86400.0, 500_000_000)
    with pytest.raises(ConfigurationError, match="--keep 'forever'"):
        parse_keep(["forever"])


def test_history_of_a_missing_database_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["history", str(tmp_path / "none.db")]) == 1
    assert "no such history database" in capsys.readouterr().err
    assert not (tmp_path / "none.db").exists()
    (tmp_path / "junk.db").write_bytes(b"not sqlite at all" * 100)
    assert main(["history", str(tmp_path / "junk.db")]) == 1
    assert "not a starterbus history database" in capsys.readouterr().err
    with pytest.raises(ConfigurationError, match="h.db: cannot open"):
        HistoryStore(tmp_path / "no" / "dir" / "h.db")
