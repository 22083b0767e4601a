"""Recording a start: CSV currents that rise and settle, the history rows, and a PNG that decodes."""

from __future__ import annotations

import csv
import json
import struct
import threading
from pathlib import Path

import matplotlib.image
import pytest

from starterbus.cli.main import main
from starterbus.core.device import open_device
from starterbus.ops.history import HistoryStore
from starterbus.ops.record import record_start

from .conftest import Line


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    length, kind = struct.unpack(">I4s", data[8:16])
    assert (length, kind) == (13, b"IHDR")
    width, height = struct.unpack(">II", data[16:24])
    return width, height


def check_png(path: Path) -> None:
    assert png_size(path) == (1000, 500)
    pixels = matplotlib.image.imread(str(path))
    assert pixels.shape[:2] == (500, 1000)
    assert len({tuple(px) for px in pixels[::4, ::4].reshape(-1, pixels.shape[2]).tolist()}) > 5  # not blank


def test_record_start_writes_csv_db_and_a_png(line: Line, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "rec"
    line.starters[2].params["ramp_time"] = 30  # 1.5 s of wall time: the current rises over the first 0.375 s
    code = main(["record", line.url(2), "--model", "jjr5000", "--start", "--yes", "-o", str(out), "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert code == 0 and summary["ended"] == "running"
    assert summary["current_limit_a"] == pytest.approx(3.5 * 390)  # 350 % of 390 A

    with Path(summary["files"]["csv"]).open(encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    amps = [float(r["current_a_A"]) for r in rows]
    states = [r["state"] for r in rows]
    peak = max(amps)
    assert states[0] == "starting" and states[-1] == "running"
    assert amps[0] < peak / 2 and peak == pytest.approx(summary["current_limit_a"], abs=0.1)  # it rises...
    starting = [a for a, s in zip(amps, states, strict=True) if s == "starting"]
    assert starting == sorted(starting)
    running = [a for a, s in zip(amps, states, strict=True) if s == "running"]
    assert len(running) >= 3 and len(set(running)) == 1 and running[0] < peak  # ...and settles at 0.8 x In
    assert running[0] == pytest.approx(0.8 * 390, abs=0.1)

    check_png(Path(summary["files"]["png"]))
    db = Path(summary["files"]["db"])
    with HistoryStore(db, create=False) as store:
        (event,) = store.events(kind="start")
        assert len(store.samples(device=event["device"])) == len(rows)
    png = tmp_path / "again.png"
    assert main(["plot", str(db), "--device", event["device"], "--event", str(event["id"]), "-o", str(png)]) == 0
    check_png(png)


def test_record_waits_for_the_next_start(line: Line) -> None:
    starter = line.starters[3]
    starter.params["ramp_time"] = 4  # 0.2 s of wall time on the fast clock
    polled = threading.Event()
    status_word = starter.status_word
    reads = []

    def start_when_watched() -> int:  # the motor starts after the recorder has read a few stopped statuses
        reads.append(1)
        if len(reads) == 5:
            polled.set()
            starter.start()
        return status_word()

    starter.status_word = start_when_watched  # type: ignore[method-assign]
    with open_device(line.url(3), "jjr5000") as dev:
        rec = record_start(dev, start=False, limit=10, settle=0.2)
    assert polled.is_set() and not rec.commanded and rec.ended == "running"
    assert rec.points[0].state == "starting" and rec.points[-1].state == "running"


def write_start_history(db: Path) -> int:
    """A history database as `poll --record` writes it: device m1 starts at t=100 (60 samples); the event's id."""
    with HistoryStore(db) as store:
        event = store.add_event(100.0, "m1", "state", "ready -> starting", detail={"from": "ready", "to": "starting"})
        store.add_event(105.0, "m1", "state", "running -> stopping", detail={"from": "running", "to": "stopping"})
        for n in range(60):
            t = 99.5 + n * 0.1
            amps = 0.0 if t < 100 else min(1000.0, (t - 100) * 2000) if t < 102 else 300.0
            state = "ready" if t < 100 else "starting" if t < 102 else "running"
            values = {"current_limit": {"value": 350}, "motor_rated_current": {"value": 390}}
            store.add_sample({"time": t, "device": "m1", "model": "jjr5000", "online": 1, "state": state,
                              "current_a": amps, "values": values})  # fmt: skip
    return event


def test_plot_a_start_from_poll_history(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db = tmp_path / "h.db"
    event = write_start_history(db)
    assert main(["plot", str(db), "--device", "m1", "--event", str(event)]) == 0
    check_png(tmp_path / f"h-m1-event-{event}.png")
    with HistoryStore(db) as store:
        trip = store.add_event(104.0, "m1", "fault", "7: motor locked rotor", code=7)
    assert main(["plot", str(db), "--device", "m1", "--event", str(trip), "-o", str(tmp_path / "trip.png")]) == 0
    check_png(tmp_path / "trip.png")
    assert main(["plot", str(db), "--device", "m2", "--event", str(event)]) == 1
    assert "is of device 'm1'" in capsys.readouterr().err
