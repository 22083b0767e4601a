"""Benchmark: what one buffered sample costs while the broker is away, in memory and in the SQLite buffer file.

Run: ``python bench/serve/store_cost.py [--devices 1000] [--metrics 10] [--samples 30000] [--dir DIR]``

The samples are ``bench/serve/throughput.py``'s synthetic ones (every value changed, so every sample is one
would-be DDATA of ``--metrics`` metrics), fed straight to :class:`EdgeSession` in this process; no broker.

* live: the node born (output discarded): the encoding of a live DDATA, for comparison;
* buffered, memory: the node not connected, :class:`MemoryStore`;
* buffered, SQLite: the node not connected, :class:`SqliteStore` (WAL, ``synchronous=NORMAL``: one commit per
  record, no fsync per commit) in ``--dir``, whose file system is printed;
* flush: after the births, ``EdgeSession.history`` in batches of 200 plus ``history_sent`` until the file is
  empty (reading, decoding, encoding as historical DDATA, deleting; publishing not included);
* reopen: opening the file with every record in it (what a restart costs before serving).

Per sample: wall and CPU time (``time.process_time``) divided by the samples; bytes per record: the file (and
its WAL) after the buffered run, divided by the records.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from starterbus.bench.serve.throughput import PROFILE, SyntheticFleet
from starterbus.fleet.poller import Sample
from starterbus.serve.history import Bounds, HistoryStore, MemoryStore
from starterbus.serve.metrics import Aliases, device_metrics, node_metrics
from starterbus.serve.session import EdgeSession, SessionOptions
from starterbus.serve.store import SqliteStore

T0 = time.time()


def make_session(source: SyntheticFleet, store: HistoryStore) -> EdgeSession:
    aliases = Aliases()
    devices = {c.name: device_metrics(c, PROFILE, aliases) for c in source.configs}
    return EdgeSession(SessionOptions("bench", "node1"), node_metrics(aliases), devices, store=store)


def samples(source: SyntheticFleet, count: int) -> list[Sample]:
    out = []
    for i in range(count):
        s = source.sample(source.configs[i % len(source.configs)], i // len(source.configs))
        out.append(dataclasses.replace(s, time=T0 + i * 1e-4))
    return out


def timed(fn: Callable[[], object]) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - wall, time.process_time() - cpu


def feed(session: EdgeSession, batch: list[Sample]) -> None:
    for s in batch:
        session.on_sample(s, s.time)


def filesystem(path: Path) -> str:
    best = ("?", "")
    with open("/proc/mounts", encoding="utf-8") as f:
        for line in f:
            _dev, mount, kind = line.split()[:3]
            if str(path.resolve()).startswith(mount) and len(mount) >= len(best[1]):
                best = (kind, mount)
    return f"{best[0]} ({best[1]})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--devices", type=int, default=1000)
    ap.add_argument("--metrics", type=int, default=10)
    ap.add_argument("--samples", type=int, default=30_000)
    ap.add_argument("--dir", type=Path, default=None, help="where the buffer file goes (default: a temp dir)")
    args = ap.parse_args()
    source = SyntheticFleet(args.devices, args.metrics)
    warm = samples(source, args.devices)  # every device reported once: later samples are all changes
    batch = samples(source, args.samples + args.devices)[args.devices :]
    n = len(batch)

    def per(seconds: float) -> str:
        return f"{seconds / n * 1e6:7.1f} us"

    live = make_session(source, MemoryStore())
    feed(live, warm)
    live.next_will()
    live.on_connected(T0)
    wall, cpu = timed(lambda: feed(live, batch))
    print(f"{n} samples of {args.metrics} metrics, {args.devices} devices")
    print(f"live DDATA (encoded, not sent)   wall {per(wall)}  cpu {per(cpu)} per sample")

    memory = make_session(source, MemoryStore(Bounds()))
    feed(memory, warm)
    wall, cpu = timed(lambda: feed(memory, batch))
    print(f"buffered, memory                 wall {per(wall)}  cpu {per(cpu)} per sample")

    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        path = Path(tmp) / "buffer.db"
        store = SqliteStore.open(path, Bounds())
        disk = make_session(source, store)
        feed(disk, warm)
        wall, cpu = timed(lambda: feed(disk, batch))
        records = len(store)
        on_disk = sum(p.stat().st_size for p in Path(tmp).iterdir() if p.name.startswith("buffer.db"))
        print(f"buffered, SQLite                 wall {per(wall)}  cpu {per(cpu)} per sample")
        print(f"  on {filesystem(Path(tmp))}, WAL, synchronous=NORMAL")
        print(
            f"  {records} records, {on_disk / records:.0f} bytes per record on disk (file + WAL), "
            f"{store.size / records:.0f} bytes of stored JSON"
        )
        store.close()
        wall, _ = timed(lambda: SqliteStore.open(path, Bounds()).close())
        print(f"reopen with {records} records     {wall * 1000:7.1f} ms")

        store = SqliteStore.open(path, Bounds())
        flushing = make_session(source, store)
        for s in warm:  # every device online, so that the births make them all born
            flushing.devices[s.device].online = True
        flushing.next_will()
        flushing.on_connected(T0)

        def flush() -> None:
            while True:
                _publishes, ids = flushing.history(T0, 200)
                if not ids:
                    return
                flushing.history_sent(ids)

        wall, cpu = timed(flush)
        assert len(store) == 0 and store.delivered == records, (len(store), store.delivered)
        print(
            f"flush (read, encode, delete)     wall {wall / records * 1e6:7.1f} us  cpu {cpu / records * 1e6:7.1f} us "
            f"per record ({records / wall:.0f} records/s)"
        )
        store.close()


if __name__ == "__main__":
    main()
