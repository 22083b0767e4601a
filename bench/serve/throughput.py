"""Benchmark: 1000 simulated devices x 10 metrics every second through ``serve`` into mosquitto.

Run: ``python bench/serve/throughput.py [--devices 1000] [--metrics 10] [--seconds 20] [--warmup 5]``

The samples come from a synthetic source (the same ``Sample`` objects the poller emits, every one of its 10
values changed since the last second, so every sample becomes a DDATA with 10 metrics), not from simulators on
ptys: the poller's own cost is measured in bench/fleet/scale.py, and this measures what ``serve`` adds on top.
Two runs, side by side, in this process:

* baseline: the source alone, its samples consumed and dropped;
* serve: the same source feeding the edge node (session, protobuf encoding, paho-mqtt) publishing to a local
  mosquitto (started here, on loopback).

Extra CPU is the difference of ``time.process_time()`` per second of wall time, as a fraction of one core
(goal < 0.10). Latency is measured by a subscriber in a child process (its CPU is not counted): receive time
minus the metric's timestamp, which is the sample's acquisition time (goal p50 < 20 ms). Broker CPU is printed
for information (from /proc).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import textwrap
import time
from collections.abc import AsyncIterator
from typing import Any, cast

from starterbus.aio import AsyncFleet
from starterbus.core.model import PointDef, Value
from starterbus.core.registry import get_profile
from starterbus.core.status import decode_status_word
from starterbus.fleet.config import DeviceConfig
from starterbus.fleet.poller import Sample
from starterbus.serve.broker import BrokerOptions
from starterbus.serve.driver import EdgeNodeDriver
from starterbus.serve.embedded import start_mosquitto
from starterbus.serve.metrics import Aliases, device_metrics, node_metrics
from starterbus.serve.session import EdgeSession, SessionOptions

PROFILE = get_profile("jjr5000")


class _Stream:
    """The synthetic samples as a subscriber's stream: nothing waits in it at a stop (generated on demand).
    Iterating it iterates the source itself, as the baseline does: no coroutine of this bench's between the
    source and serve, whose cost would be counted as serve's."""

    def __init__(self, source: AsyncIterator[Sample]) -> None:
        self._source = source

    def __aiter__(self) -> AsyncIterator[Sample]:
        return self._source

    def drain(self) -> list[Sample]:
        return []

    def close(self) -> None:
        pass


class SyntheticFleet:
    """``devices`` JJR5000s, each sampled once per ``period``, spread evenly over it, all values changing."""

    def __init__(self, devices: int, metrics: int, period: float = 1.0) -> None:
        points = [p for p in PROFILE.measurements if p.enum is None and p.key not in ("control_word", "status_word")]
        points += [p for p in PROFILE.parameters if p.enum is None and p.raw_max - p.raw_min > 100]
        self.points: list[PointDef] = points[:metrics]
        meas = tuple(p.key for p in self.points if p in PROFILE.measurements)
        params = tuple(p.key for p in self.points if p not in PROFILE.measurements)
        self.configs = [
            DeviceConfig(f"d{i:04d}", "l1", "jjr5000", "synthetic", i, period, meas, params) for i in range(devices)
        ]
        self.period = period
        self.status = decode_status_word(0x2200, PROFILE.faults)  # running, ready
        self.emitted = 0

    def sample(self, config: DeviceConfig, round_: int) -> Sample:
        values = {}
        for j, p in enumerate(self.points):
            raw = p.raw_min + (config.address or 0) + j + round_ % 50
            values[p.key] = Value.from_raw(p, min(raw, p.raw_max))
        return Sample(config.name, "l1", "jjr5000", time.time(), True, self.status, values, None, 0)

    def subscribe(self) -> _Stream:
        """What serve's driver reads (as :meth:`AsyncFleet.subscribe <starterbus.aio.AsyncFleet.subscribe>`)."""
        return _Stream(self.samples())

    async def samples(self) -> AsyncIterator[Sample]:
        slot = 0.005
        per_slot = max(1, round(len(self.configs) * slot / self.period))
        start = time.monotonic()
        index = 0
        round_ = 0
        while True:
            for _ in range(per_slot):
                yield self.sample(self.configs[index], round_)
                self.emitted += 1
                index += 1
                if index == len(self.configs):
                    index, round_ = 0, round_ + 1
            due = start + (self.emitted / len(self.configs)) * self.period
            delay = due - time.monotonic()
            if delay > 0:
                await asyncio.sleep(delay)


SUBSCRIBER = textwrap.dedent(
    """
    import json, sys, time, threading
    import paho.mqtt.client as mqtt
    from paho.mqtt.enums import CallbackAPIVersion
    from starterbus.serve.schema import Payload
    port, t0, t1 = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
    lat = []
    def on_message(c, u, msg):
        now = time.time() * 1000
        p = Payload(); p.ParseFromString(msg.payload)
        if p.metrics and t0 * 1000 <= p.metrics[0].timestamp <= t1 * 1000:
            lat.append(now - p.metrics[0].timestamp)
    ready = threading.Event()
    c = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="bench-sub")
    c.on_message = on_message
    c.on_connect = lambda c, *a: c.subscribe("spBv1.0/bench/DDATA/#")
    c.on_subscribe = lambda *a: ready.set()
    c.connect("127.0.0.1", port, 30); c.loop_start(); ready.wait(10); print("ready", flush=True)
    while time.time() < t1 + 2: time.sleep(0.1)
    c.loop_stop(); lat.sort(); n = len(lat)
    q = lambda f: round(lat[min(n - 1, int(f * n))], 2) if n else None
    print(json.dumps({"count": n, "p50": q(0.5), "p95": q(0.95), "p99": q(0.99), "max": q(1.0)}))
    """
)


def proc_cpu(pid: int) -> float:
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


async def baseline(source: SyntheticFleet, warmup: float, seconds: float) -> float:
    end_warm = time.monotonic() + warmup
    cpu0 = wall0 = 0.0
    measuring = False
    async for _sample in source.samples():
        now = time.monotonic()
        if not measuring and now >= end_warm:
            measuring, cpu0, wall0 = True, time.process_time(), now
        if measuring and now - wall0 >= seconds:
            return (time.process_time() - cpu0) / (now - wall0)
    return 0.0


async def with_serve(source: SyntheticFleet, port: int, warmup: float, seconds: float) -> tuple[float, int]:
    aliases = Aliases()
    node = node_metrics(aliases)
    devices = {c.name: device_metrics(c, PROFILE, aliases) for c in source.configs}
    session = EdgeSession(SessionOptions("bench", "node1", refresh=0), node, devices)
    broker = BrokerOptions("127.0.0.1", port, client_id="bench-node")
    driver = EdgeNodeDriver(cast(AsyncFleet, source), session, broker)
    stop = asyncio.Event()
    task = asyncio.create_task(driver.run(stop))
    await asyncio.sleep(warmup)
    cpu0, wall0, sent0 = time.process_time(), time.monotonic(), session.published
    await asyncio.sleep(seconds)
    cpu = (time.process_time() - cpu0) / (time.monotonic() - wall0)
    sent = session.published - sent0
    stop.set()
    await task
    return cpu, sent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0] if __doc__ else None)
    ap.add_argument("--devices", type=int, default=1000)
    ap.add_argument("--metrics", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--warmup", type=float, default=5.0)
    args = ap.parse_args()

    base = asyncio.run(baseline(SyntheticFleet(args.devices, args.metrics), args.warmup, args.seconds))
    broker = start_mosquitto()
    try:
        t0 = time.time() + args.warmup
        t1 = t0 + args.seconds
        sub = subprocess.Popen(
            [sys.executable, "-c", SUBSCRIBER, str(broker.port), str(t0), str(t1)], stdout=subprocess.PIPE, text=True
        )
        assert sub.stdout is not None
        assert sub.stdout.readline().strip() == "ready"
        broker_cpu0 = proc_cpu(broker.process.pid)
        source = SyntheticFleet(args.devices, args.metrics)
        cpu, sent = asyncio.run(with_serve(source, broker.port, args.warmup, args.seconds))
        broker_cpu = (proc_cpu(broker.process.pid) - broker_cpu0) / (args.seconds + args.warmup)
        latency: dict[str, Any] = json.loads(sub.stdout.readline())
        sub.wait(10)
    finally:
        broker.close()
    rate = sent / args.seconds
    print(f"{args.devices} devices x {len(source.points)} metrics every 1 s, {args.seconds:g} s measured")
    print(f"  baseline (source only)     CPU {base:6.3f} core")
    print(f"  with serve -> mosquitto    CPU {cpu:6.3f} core   published {rate:7.0f} msg/s")
    print(
        f"  extra CPU of serve         {cpu - base:6.3f} core  (goal < 0.10)   ratio {cpu / base if base else 0:5.1f}x"
    )
    print(f"  mosquitto                  CPU {broker_cpu:6.3f} core")
    print(
        f"  sample -> subscriber latency over {latency['count']} DDATA: p50 {latency['p50']} ms, "
        f"p95 {latency['p95']} ms, p99 {latency['p99']} ms, max {latency['max']} ms  (goal p50 < 20 ms)"
    )


if __name__ == "__main__":
    main()
