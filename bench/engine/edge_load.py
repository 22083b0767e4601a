"""Benchmark: selectors or asyncio for the I/O scheduler, under the same mixed load (docs/engine.md, "Choice").

Run: ``python bench/engine/edge_load.py [--connections 16] [--units 62] [--period 1.0] [--seconds 20]
[--warmup 3] [--pairs 3] [--metrics 10]`` (``--pairs``: rounds of the three runs below)

The load: ``--connections`` Modbus TCP connections to one responder process (this script with ``--serve``: it
answers every FC03 at once, in a process of its own so that its CPU is not counted), ``--units`` devices behind
each (16 x 62 = 992 devices), each polled once per ``--period`` (one FC03 of 4 registers; the polls spread
evenly over the period, each connection's too), one transaction on the wire per connection at a time. Every
answer becomes a sample that an asyncio consumer turns into a Sparkplug DDATA payload of ``--metrics`` metrics
(``serve/payloads.py``'s ``encode``: what ``serve`` spends per sample, without the broker), as ``serve`` and
``opcua`` consume ``AsyncFleet``'s samples.

The same drivers and engines (``TcpDriver`` + ``MbapEngine``: every poll a ticket with a future whose done
callback makes the sample), run three ways, each run in a fresh process:

* ``selectors`` (the baseline: today): a :class:`~starterbus.core.scheduler.Scheduler` in its own thread
  (``starterbus-io``), the polls paced by a deadline-only driver; the asyncio edge in the main thread (the
  default event loop, as ``serve`` runs), fed by ``call_soon_threadsafe`` per sample, as ``AsyncFleet`` is;
* ``asyncio``: one ``SelectorEventLoop(SelectSelector())`` (microsecond timeouts, as the scheduler's ``select``)
  runs the drivers (``add_reader`` / ``add_writer`` on their descriptors, ``call_at`` on their deadlines: a
  minimal asyncio scheduler, in this file, not the full one) and the edge consumer: a sample is a
  ``put_nowait``, no hand-off;
* ``inline`` (to tell the two apart, not a design): the selectors run with each sample encoded in the
  scheduler's thread as it comes (no asyncio, no hand-off: what the thread hop costs, and the loop delays of an
  edge sharing the I/O thread without asyncio's own machinery).

Measured over the window (``--seconds`` after ``--warmup``): transactions completed per second against the plan
(devices / period), the process's CPU (``time.process_time()``: the poller and the edge together) as a fraction
of a core and per transaction, the poll latency (from when the poll was due to its answer decoded: pacing,
queueing behind the connection's previous transaction, the round trip and any delay of the loop) and the edge
latency (from the answer decoded to the consumer taking the sample) at p50 and p99. Rounds rotate the order;
each run is printed as ratios against the selectors run of its round. No assertion: the decision rule
(docs/engine.md) is printed with the medians.
"""

from __future__ import annotations

import argparse
import asyncio
import functools
import json
import math
import os
import selectors
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

from starterbus.bench.engine.edge_parts import AsyncioDrivers, Encoder, serve
from starterbus.core.engine import Ticket, TicketState
from starterbus.core.errors import StarterbusError
from starterbus.core.media import TcpDriver
from starterbus.core.scheduler import Scheduler
from starterbus.transports.modbus.codec.frames import ReadRequest, ReadResponse
from starterbus.transports.modbus.master.exchange import Exchange, TransactionPolicy
from starterbus.transports.modbus.master.mbap import MbapEngine

MODES = ("selectors", "asyncio", "inline")
REGISTERS = 4


# -- what both loops share --------------------------------------------------------------------------------------


@dataclass(slots=True)
class Plan:
    connections: int
    units: int
    period: float
    warmup: float
    seconds: float
    metrics: int


@dataclass
class Run:
    """One device fleet polled by one loop: the pacing, the samples, the figures."""

    plan: Plan
    drivers: list[TcpDriver[MbapEngine]]
    emit: Callable[[tuple[int, tuple[int, ...], float]], object]
    mark_due: Callable[[TcpDriver[MbapEngine]], None]
    start: float = 0.0
    window: tuple[float, float] = (0.0, 0.0)
    poll_latency: list[float] = field(default_factory=list)
    edge_latency: list[float] = field(default_factory=list)
    done: int = 0
    failed: int = 0
    cpu: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        policy = TransactionPolicy(timeout=0.5, retries=0)
        self.exchanges = [  # device n on connection n % connections: each connection's polls spread over the period
            Exchange(ReadRequest(unit + 1, 0x0100, REGISTERS), policy, 0.0)
            for unit in range(self.plan.units)
            for _ in range(self.plan.connections)
        ]
        self.count = len(self.exchanges)
        self.next_index = 0
        self.round = 0

    def begin(self, now: float) -> None:
        self.start = now + 0.05
        opens = self.start + self.plan.warmup
        self.window = (opens, opens + self.plan.seconds)

    @property
    def next_due(self) -> float:
        return self.start + self.round * self.plan.period + self.next_index * self.plan.period / self.count

    def pace(self, now: float) -> None:
        """Submit every poll that is due."""
        while self.next_due <= now:
            device = self.next_index
            due = self.next_due
            driver = self.drivers[device % self.plan.connections]
            future: Future[Any] = Future()
            future.add_done_callback(functools.partial(self.answered, device, due))
            driver.submit([self.exchanges[device]], now, [future])
            self.mark_due(driver)
            self.next_index += 1
            if self.next_index == self.count:
                self.next_index, self.round = 0, self.round + 1

    def answered(self, device: int, due: float, future: Future[Any]) -> None:  # in the loop
        now = time.monotonic()
        ticket: Ticket[Any, Any] = future.result()
        opens, closes = self.window
        if opens <= now < closes:
            if ticket.state is TicketState.DONE:
                self.done += 1
                self.poll_latency.append(now - due)
            else:
                self.failed += 1
        if ticket.state is TicketState.DONE:
            response = ticket.result
            assert isinstance(response, ReadResponse) and response.values[-1] == response.unit
            self.emit((device, response.values, now))

    def measure(self) -> None:
        self.cpu.append(time.process_time())


async def edge(queue: asyncio.Queue[tuple[int, tuple[int, ...], float]], run: Run) -> None:
    """The asyncio consumer of the samples (the edge latency: from the answer decoded to here)."""
    encoder = Encoder(run.plan.metrics)
    opens, closes = run.window
    while True:
        sample = await queue.get()
        if opens <= sample[2] < closes:
            run.edge_latency.append(time.monotonic() - sample[2])
        encoder(sample)


def make_drivers(port: int, plan: Plan) -> list[TcpDriver[MbapEngine]]:
    return [
        TcpDriver("127.0.0.1", port, functools.partial(MbapEngine, outstanding=1, name=f"c{c}"), 2.0)
        for c in range(plan.connections)
    ]


async def window(run: Run) -> None:
    """Wait for the window, note the CPU at its ends, and let what is in flight at its close finish."""
    opens, closes = run.window
    await asyncio.sleep(max(0.0, opens - time.monotonic()))
    run.measure()
    await asyncio.sleep(max(0.0, closes - time.monotonic()))
    run.measure()
    await asyncio.sleep(0.2)


# -- (a) the scheduler's selectors loop in its own thread, the asyncio edge in the main thread -------------------


class Pacer:
    """A deadline-only driver of the scheduler: submits the polls that are due."""

    name = "pacer"
    fd = -1
    writing = False

    def __init__(self, run: Run) -> None:
        self.run = run

    @property
    def deadline(self) -> float:
        return self.run.next_due

    def step(self, now: float, ready: bool) -> None:
        self.run.pace(now)

    def submit(self, requests: Any, now: float, futures: Any) -> list[Ticket[Any, Any]]:
        raise NotImplementedError

    def withdraw(self, tickets: Any, now: float) -> None: ...

    def cancel(self, futures: Any, now: float) -> None: ...

    def crash(self, error: StarterbusError, now: float) -> None:
        raise SystemExit(f"pacer: {error}")


def run_selectors(port: int, plan: Plan, inline: bool = False) -> Run:
    """``inline``: the samples encoded in the scheduler's thread as they come (no asyncio edge, no hand-off)."""
    loop = Scheduler()
    edge_loop = asyncio.new_event_loop()
    queue: asyncio.Queue[tuple[int, tuple[int, ...], float]] = asyncio.Queue()
    drivers = make_drivers(port, plan)
    emit = Encoder(plan.metrics) if inline else lambda s: edge_loop.call_soon_threadsafe(queue.put_nowait, s)
    run = Run(plan, drivers, emit, loop.due)

    def add(driver: TcpDriver[MbapEngine], now: float) -> Future[None]:
        loop.add(driver)
        return driver.open(now)

    for driver in drivers:
        opened = loop.wait(loop.call(functools.partial(add, driver)), 5.0, "add")
        loop.wait(opened, 5.0, f"{driver.name}: connect")
    pacer = Pacer(run)

    def add_pacer(now: float) -> None:
        run.begin(now)
        loop.add(pacer)

    loop.wait(loop.call(add_pacer), 5.0, "pacer")
    loop.start()

    async def main() -> None:
        consumer = asyncio.create_task(edge(queue, run))
        await window(run)
        consumer.cancel()

    try:
        edge_loop.run_until_complete(main() if not inline else window(run))
    finally:
        loop.stop()
        edge_loop.close()
    return run


# -- (b) one asyncio loop for the drivers and the edge ----------------------------------------------------------


def run_asyncio(port: int, plan: Plan) -> Run:
    loop = asyncio.SelectorEventLoop(selectors.SelectSelector())
    drivers_loop = AsyncioDrivers(loop)
    queue: asyncio.Queue[tuple[int, tuple[int, ...], float]] = asyncio.Queue()
    drivers = make_drivers(port, plan)
    run = Run(plan, drivers, queue.put_nowait, drivers_loop.due)

    def pace() -> None:
        run.pace(time.monotonic())
        loop.call_at(run.next_due, pace)

    async def main() -> None:
        for driver in drivers:
            opened = driver.open(time.monotonic())
            drivers_loop.sync(driver)
            await asyncio.wrap_future(opened)
        run.begin(time.monotonic())
        loop.call_at(run.next_due, pace)
        consumer = asyncio.create_task(edge(queue, run))
        await window(run)
        consumer.cancel()

    try:
        loop.run_until_complete(main())
    finally:
        loop.close()
    return run


# -- the runs and the report -------------------------------------------------------------------------------------


def child(mode: str, port: int, plan: Plan) -> dict[str, Any]:
    run = run_asyncio(port, plan) if mode == "asyncio" else run_selectors(port, plan, inline=mode == "inline")
    cpu = run.cpu[1] - run.cpu[0]
    transactions = max(1, run.done)

    def pct(values: list[float], q: float) -> float:
        return sorted(values)[min(len(values) - 1, int(q * len(values)))] * 1000 if values else math.nan

    return {
        "mode": mode,
        "rate": run.done / plan.seconds / (plan.connections * plan.units / plan.period),
        "failed": run.failed,
        "core": cpu / plan.seconds,
        "us_per_tx": cpu / transactions * 1e6,
        "poll_p50": pct(run.poll_latency, 0.5),
        "poll_p99": pct(run.poll_latency, 0.99),
        "edge_p50": pct(run.edge_latency, 0.5),
        "edge_p99": pct(run.edge_latency, 0.99),
        "load": os.getloadavg()[0],
    }


def one(mode: str, port: int, args: argparse.Namespace) -> dict[str, Any]:
    command = [sys.executable, __file__, "--child", mode, "--port", str(port)]
    for name in ("connections", "units", "period", "seconds", "warmup", "metrics"):
        command += [f"--{name}", str(getattr(args, name))]
    out = subprocess.run(command, capture_output=True, text=True, check=True)
    result: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def show(result: dict[str, Any], base: dict[str, Any] | None) -> str:
    text = (
        f"{result['mode']:<9} rate {result['rate']:.4f} of plan, failed {result['failed']}, "
        f"{result['core']:.3f} core, {result['us_per_tx']:.0f} us/tx, poll p50/p99 {result['poll_p50']:.2f}/"
        f"{result['poll_p99']:.2f} ms, edge p50/p99 {result['edge_p50']:.2f}/{result['edge_p99']:.2f} ms, "
        f"load {result['load']:.1f}"
    )
    if base is not None:
        ratios = " ".join(
            f"{key} {result[key] / base[key]:.2f}x"
            for key in ("us_per_tx", "poll_p50", "poll_p99", "edge_p50", "edge_p99")
        )
        text += f"\n          vs selectors of its round: {ratios}, rate {result['rate'] - base['rate']:+.4f}"
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--connections", type=int, default=16)
    parser.add_argument("--units", type=int, default=62)
    parser.add_argument("--period", type=float, default=1.0)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--warmup", type=float, default=3.0)
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--metrics", type=int, default=10)
    parser.add_argument("--serve", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--child", choices=MODES, help=argparse.SUPPRESS)
    parser.add_argument("--port", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        serve()
        return
    plan = Plan(args.connections, args.units, args.period, args.warmup, args.seconds, args.metrics)
    if args.child:
        print(json.dumps(child(args.child, args.port, plan)))
        return
    responder = subprocess.Popen([sys.executable, __file__, "--serve"], stdout=subprocess.PIPE, text=True)
    try:
        assert responder.stdout is not None
        port = int(responder.stdout.readline())
        devices = f"{plan.connections} connections x {plan.units} devices"
        print(f"{devices} every {plan.period:g} s, {plan.metrics} metrics a sample")
        ratios: dict[str, list[float]] = {mode: [] for mode in MODES[1:]}
        gaps: dict[str, list[float]] = {mode: [] for mode in MODES[1:]}
        for pair in range(args.pairs):
            order = MODES[pair % len(MODES) :] + MODES[: pair % len(MODES)]
            results = {mode: one(mode, port, args) for mode in order}
            base = results["selectors"]
            print(f"round {pair + 1} ({', '.join(order)}):")
            print("  " + show(base, None))
            for mode in MODES[1:]:
                print("  " + show(results[mode], base))
                ratios[mode].append(results[mode]["us_per_tx"] / base["us_per_tx"])
                gaps[mode].append(results[mode]["rate"] - base["rate"])
        for mode in MODES[1:]:
            cpu, gap = statistics.median(ratios[mode]), statistics.median(gaps[mode])
            print(
                f"median: {mode}'s CPU per transaction {cpu:.2f}x the selectors run's, its rate {gap:+.4f} of the plan"
            )
        cpu, gap = statistics.median(ratios["asyncio"]), statistics.median(gaps["asyncio"])
        rule = "asyncio" if gap >= -0.005 and cpu <= 1.1 else "selectors"
        print(f"the rule of docs/engine.md (rate within 0.005, CPU at most 1.1x) on these figures: {rule}")
    finally:
        responder.kill()
        responder.wait()


if __name__ == "__main__":
    main()
