"""Soak: ``serve`` over minutes while mosquitto is stopped and restarted; memory must stay flat.

Run: ``python bench/serve/soak.py [--minutes 3] [--devices 200] [--metrics 10] [--up 20] [--down 5]
[--buffer-messages 2000]``

The synthetic source of bench/serve/throughput.py feeds the edge node (``devices`` samples per second, every
value changing). mosquitto runs ``--up`` seconds, is stopped for ``--down`` seconds (the node buffers DDATA up to
``--buffer-messages``, dropping and counting the oldest), then restarted on the same port, over and over. After
each cycle the script prints the resident set (VmRSS), the Python heap (tracemalloc, traced from the start),
bdSeq, the buffer and the dropped count. Flat memory means the last cycles' heap is no larger than the first's
beyond noise; the buffer bound caps what the outage can hold.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import time
import tracemalloc
from pathlib import Path
from typing import Any, cast

from starterbus.aio import AsyncFleet
from starterbus.core.registry import get_profile
from starterbus.serve.broker import BrokerOptions
from starterbus.serve.driver import EdgeNodeDriver
from starterbus.serve.embedded import free_port, start_mosquitto
from starterbus.serve.metrics import Aliases, device_metrics, node_metrics
from starterbus.serve.session import EdgeSession, SessionOptions


def _synthetic() -> Any:
    spec = importlib.util.spec_from_file_location("serve_throughput", Path(__file__).with_name("throughput.py"))
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.SyntheticFleet


def rss_kib() -> int:
    for line in Path("/proc/self/status").read_text(encoding="ascii").splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


async def soak(args: argparse.Namespace) -> None:
    source = _synthetic()(args.devices, args.metrics)
    aliases = Aliases()
    node = node_metrics(aliases)
    profile = get_profile("jjr5000")
    devices = {c.name: device_metrics(c, profile, aliases) for c in source.configs}
    options = SessionOptions("soak", "node1", refresh=0, buffer_messages=args.buffer_messages)
    session = EdgeSession(options, node, devices)
    port = free_port()
    broker = await asyncio.to_thread(start_mosquitto, port)
    driver = EdgeNodeDriver(
        cast(AsyncFleet, source), session, BrokerOptions("127.0.0.1", port, client_id="soak"), retry_delay=0.5
    )
    stop = asyncio.Event()
    task = asyncio.create_task(driver.run(stop))
    end = time.monotonic() + args.minutes * 60
    print(f"{args.devices} devices x {args.metrics} metrics/s; mosquitto up {args.up:g} s, down {args.down:g} s")
    head = ("cycle", "t s", "RSS MiB", "heap MiB", "bdSeq", "sessions", "published", "dropped")
    print(" ".join(f"{h:>{w}}" for h, w in zip(head, (5, 6, 8, 9, 5, 8, 9, 8), strict=True)))
    first_heap = None
    cycle = 0
    start = time.monotonic()
    try:
        while time.monotonic() < end:
            await asyncio.sleep(args.up)
            await asyncio.to_thread(broker.close)
            await asyncio.sleep(args.down)
            broker = await asyncio.to_thread(start_mosquitto, port)
            cycle += 1
            heap = tracemalloc.get_traced_memory()[0] / 2**20
            first_heap = first_heap if first_heap is not None else heap
            print(
                f"{cycle:5d} {time.monotonic() - start:6.0f} {rss_kib() / 1024:8.1f} {heap:9.2f} {session.bdseq:5d} "
                f"{driver.connections:8d} {session.published:9d} {session.dropped:8d}",
                flush=True,
            )
    finally:
        stop.set()
        await task
        broker.close()
    heap = tracemalloc.get_traced_memory()[0] / 2**20
    print(f"heap after the first cycle {first_heap:.2f} MiB, at the end {heap:.2f} MiB")


def main() -> None:
    ap = argparse.ArgumentParser(description="serve soak with broker restarts")
    ap.add_argument("--minutes", type=float, default=3.0)
    ap.add_argument("--devices", type=int, default=200)
    ap.add_argument("--metrics", type=int, default=10)
    ap.add_argument("--up", type=float, default=20.0)
    ap.add_argument("--down", type=float, default=5.0)
    ap.add_argument("--buffer-messages", type=int, default=2000)
    args = ap.parse_args()
    tracemalloc.start()
    asyncio.run(soak(args))


if __name__ == "__main__":
    main()
