"""The store-and-forward buffer: the same behaviour in memory and in SQLite; the file survives its process, a
corrupt file is moved aside, and a full disk drops (and counts) records instead of stopping the edge node."""

from __future__ import annotations

import sqlite3
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from starterbus.serve.history import Bounds, HistoryStore, MemoryStore, encode_values
from starterbus.serve.store import SqliteStore, default_buffer_file

T = 1_800_000_000_000  # ms
StoreFactory = Callable[[Bounds], HistoryStore]


@pytest.fixture(params=["memory", "sqlite"])
def make_store(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[StoreFactory]:
    stores: list[HistoryStore] = []

    def make(bounds: Bounds) -> HistoryStore:
        store: HistoryStore = (
            MemoryStore(bounds)
            if request.param == "memory"
            else SqliteStore.open(tmp_path / f"b{len(stores)}.db", bounds)
        )
        stores.append(store)
        return store

    yield make
    for s in stores:
        s.close()


def values(i: int) -> list[tuple[str, float | None, int]]:
    return [("Measurements/a", float(i), T + i), ("Status/Fault Text", None, T + i)]


def test_oldest_first_per_device_and_kept_until_removed(make_store: StoreFactory) -> None:
    store = make_store(Bounds())
    for i in range(5):
        store.append("pump" if i % 2 else "fan", values(i), T + i)
    assert dict(store.pending()) == {"fan": 3, "pump": 2} and len(store) == 5
    pump = store.take(["pump"], 10)
    assert [(r.device, r.values[0][1]) for r in pump] == [("pump", 1.0), ("pump", 3.0)]
    assert pump[0].values == tuple(values(1))
    assert [r.values[0][1] for r in store.take(["pump", "fan"], 3)] == [0.0, 1.0, 2.0]
    assert len(store) == 5  # taking is not removing
    store.remove([r.id for r in pump])
    store.discard([store.take(["fan"], 1)[0].id])
    assert dict(store.pending()) == {"fan": 2}
    assert (store.buffered, store.delivered, store.dropped) == (5, 2, 1)


def test_bounds_drop_the_oldest_and_count_them(make_store: StoreFactory) -> None:
    size = len(encode_values(values(0)))
    by_count = make_store(Bounds(messages=3))
    by_size = make_store(Bounds(size=2 * size + 1))
    by_age = make_store(Bounds(age=10.0))
    for i in range(6):
        for store in (by_count, by_size, by_age):
            store.append("pump", values(i), T + i)
    assert [r.values[0][1] for r in by_count.take(["pump"], 10)] == [3.0, 4.0, 5.0] and by_count.dropped == 3
    assert [r.values[0][1] for r in by_size.take(["pump"], 10)] == [4.0, 5.0] and by_size.dropped == 4
    by_age.expire(T + 10_003)  # older than T + 3 goes
    assert [r.values[0][1] for r in by_age.take(["pump"], 10)] == [3.0, 4.0, 5.0] and by_age.dropped == 3


def test_the_file_survives_its_process(tmp_path: Path) -> None:
    path = default_buffer_file(tmp_path / "serve-g-n.json")
    assert path.name == "serve-g-n.buffer.db"
    first = SqliteStore.open(path, Bounds(messages=4))
    for i in range(6):
        first.append("pump", values(i), T + i)
    first.remove([first.take(["pump"], 1)[0].id])
    # no close: as after kill -9, what was committed is what the next process reads
    second = SqliteStore.open(path, Bounds(messages=4))
    assert [r.values[0][1] for r in second.take(["pump"], 10)] == [3.0, 4.0, 5.0]
    assert (len(second), second.buffered, second.delivered, second.dropped) == (3, 6, 1, 2)
    second.append("pump", values(6), T + 6)
    assert [r.values[0][1] for r in second.take(["pump"], 10)] == [3.0, 4.0, 5.0, 6.0]  # in order after the old
    first.close()
    second.close()


def test_a_corrupt_file_is_moved_aside(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "buffer.db"
    path.write_bytes(b"not a database, " * 512)
    store = SqliteStore.open(path)
    aside = [p for p in tmp_path.iterdir() if p.name.startswith("buffer.db.corrupt-")]
    assert len(aside) == 1 and aside[0].read_bytes().startswith(b"not a database")
    assert str(aside[0]) in caplog.text
    store.append("pump", values(0), T)
    assert len(store) == 1
    store.close()


def failing(store: SqliteStore) -> object:
    return store.failing  # read through a call: mypy would keep an earlier assert's narrowing


def test_a_full_disk_drops_and_counts_then_recovers(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    store = SqliteStore.open(tmp_path / "buffer.db")
    store.append("pump", values(0), T)
    pages = store.db.execute("PRAGMA page_count").fetchone()[0]
    store.db.execute(f"PRAGMA max_page_count = {pages}")  # the file cannot grow: SQLITE_FULL, as on a full disk
    big = [("Status/Fault Text", "x" * 20_000, T + 1)]
    store.append("pump", big, T + 1)
    store.append("pump", big, T + 2)
    assert (len(store), store.buffered, store.dropped) == (1, 1, 2) and failing(store) is not None
    assert caplog.text.count("store failed") == 1  # logged once per episode
    store.db.execute("PRAGMA max_page_count = 1000000")
    store.append("pump", values(3), T + 3)
    assert (len(store), store.buffered, store.dropped) == (2, 2, 2) and failing(store) is None
    store.close()
    again = SqliteStore.open(tmp_path / "buffer.db")
    assert (again.buffered, again.dropped) == (2, 2)  # the drops were saved with the next commit
    again.close()


def test_session_discards_what_the_fleet_no_longer_has(tmp_path: Path) -> None:
    from starterbus.core.registry import get_profile
    from starterbus.fleet.config import DeviceConfig
    from starterbus.serve.metrics import Aliases, device_metrics, node_metrics
    from starterbus.serve.session import EdgeSession, SessionOptions

    store = SqliteStore.open(tmp_path / "buffer.db")
    store.append("gone", values(0), T)
    store.append("pump", values(1), T + 1)
    aliases = Aliases()
    config = DeviceConfig("pump", "l1", "jjr5000", "x", 2, 1.0, ("phase_a_current",), ())
    devices = {"pump": device_metrics(config, get_profile("jjr5000"), aliases, 1.0)}
    EdgeSession(SessionOptions("g", "n"), node_metrics(aliases), devices, store=store)
    assert dict(store.pending()) == {"pump": 1} and store.dropped == 1
    store.close()


def test_sqlite_errors_are_not_raised(tmp_path: Path) -> None:
    store = SqliteStore.open(tmp_path / "buffer.db")
    store.append("pump", values(0), T)
    store.db.close()  # every later call fails inside SQLite
    store.append("pump", values(1), T + 1)
    assert store.take(["pump"], 10) == [] and store.dropped == 1
    store.remove([1])
    store.expire(T + 10**12)
    with pytest.raises(sqlite3.ProgrammingError):
        store.db.execute("SELECT 1")
