"""CPU per Modbus FC03 transaction against a hand-written exact-length floor, side by side (issue 14, item 4).

    python bench/modbus/cpu_floor.py [--tx 50] [--rounds 200] [--changing] [--watch-floor] [--before DIR]

On a bare pty hop (``line_emulator.py`` without pacing) to a plain pymodbus server, nominal 19200 baud, one
process opens every client on the same port and measures them in turn, ``--tx`` transactions each, round after
round, each round in a rotated order: the floor (``clients.exact_ops``: sleep out the 3.5-character silence,
write, ``select``, read exactly the predicted length), starterbus's raw ``read_registers`` and ``Device.read``
of the same four registers. Short turns interleaved this finely see the same machine, so the ratios of the
totals are robust to what else it is doing; the median of the per-round ratios is printed too (paired: the
clients of one round ran under the same load). A few transactions before each turn are not counted (the first
request after another client's must find the line silent). ``--watch-floor`` adds a fourth client, the same
loop watching the line during the silence after each answer (as starterbus does for the trailing-bytes rule)
instead of sleeping before the request, and the ratios to it. ``--before DIR`` (A/B in one process) adds
``before``: ``read_registers`` through the ``RtuLine`` of ``DIR/starterbus/transports/modbus/driver/line.py`` (an
untouched copy of an older tree; its imports are this tree's modules), on the same link, its turns interleaved
with the others', and prints the ratio of this tree's ``read_registers`` to it. ``--served`` adds ``served``:
``read_registers`` while the process's scheduler runs its own thread (as under ``serve`` or ``poll``), where the
transaction is a ticket of the line's ``RtuJobDriver`` run by that thread (the CPU counted is the process's: both
threads). Not run by the tests.
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import statistics
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

from starterbus.bench.modbus import clients, throughput
from starterbus.core.media.keeper import Holder
from starterbus.core.scheduler import scheduler as process_scheduler

BAUD = 19200
WARM = 5  # transactions before each turn, not counted


def cpu_per_tx(op: Callable[[], object], count: int, warm: int = 50) -> float:
    """Microseconds of this process's CPU per call of ``op`` (after ``warm`` calls not counted)."""
    for _ in range(warm):
        op()
    start = time.process_time()
    for _ in range(count):
        op()
    return (time.process_time() - start) / count * 1e6


#: where the modules an older ``line.py`` imports live since the package took the protocol layout (issue 29)
MOVED = {"crc": "codec.crc", "frames": "codec.frames", "timing": "codec.timing", "receiver": "codec.receiver",
         "exchange": "master.exchange", "guard": "master.guard", "link": "driver.link"}  # fmt: skip


def before_line_class(tree: str) -> type[Any]:
    """The ``RtuLine`` class of an older tree's ``line.py``, loaded beside this tree's (its imports are ours: a
    tree from before the protocol layout imports the modules under their old names, aliased here)."""
    modbus = Path(tree) / "starterbus" / "transports" / "modbus"
    path = next((p for p in (modbus / "driver" / "line.py", modbus / "line.py") if p.exists()), modbus / "line.py")
    spec = importlib.util.spec_from_file_location("cpu_floor_before_line", path)
    if spec is None or spec.loader is None:
        raise SystemExit(f"--before: no line.py at {path}")
    for old, new in MOVED.items():
        sys.modules.setdefault(
            f"starterbus.transports.modbus.{old}", importlib.import_module(f"starterbus.transports.modbus.{new}")
        )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    line_class: type[Any] = module.RtuLine
    return line_class


def before_op(raw: Callable[[], object], tree: str) -> Callable[[], object]:
    """``read_registers`` as ``raw`` does it, through the older tree's line on the same link."""
    assert isinstance(raw, partial)
    transport = raw.func.__self__  # type: ignore[attr-defined]
    line = transport.line
    old = copy.copy(transport)  # its own caches and counters, the older line
    old._counters = type(transport.counters())()
    old._reads = {}
    old._line = before_line_class(tree)(lambda: line.link, line.settings)
    return partial(old.read_registers, *raw.args)


def served_turn(op: Callable[[], object]) -> Callable[[int, int], float]:
    """A turn of ``op`` while the process's scheduler runs its own thread (held for the turn, not counted)."""

    def turn(count: int, warm: int) -> float:
        loop, holder = process_scheduler(), Holder("cpu_floor")
        loop.hold(holder)
        try:
            return cpu_per_tx(op, count, warm)
        finally:
            loop.unhold(holder)

    return turn


def open_clients(
    port: str, watch_floor: bool, before: str | None = None
) -> tuple[dict[str, Callable[[], object]], list[Callable[[], None]]]:
    ops: dict[str, Callable[[], object]] = {}
    closers: list[Callable[[], None]] = []
    floors = [("floor", False), ("watch", True)] if watch_floor else [("floor", False)]
    for name, watch in floors:
        ops[name], close = clients.exact_ops(port, BAUD, "fc03", True, watch=watch)
        closers.append(close)
    for name, device_level in (("raw", False), ("device", True)):
        ops[name], close = clients.starterbus_ops(port, BAUD, "fc03", device_level)
        closers.append(close)
    if before is not None:
        ops["before"] = before_op(ops["raw"], before)
    return ops, closers


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tx", type=int, default=50, help="transactions per client and round")
    parser.add_argument("--rounds", type=int, default=200)
    parser.add_argument("--changing", action="store_true", help="every FC03 answer differs (pymodbus server)")
    parser.add_argument("--watch-floor", action="store_true", help="also the floor that watches the silence")
    parser.add_argument("--before", metavar="DIR", help="A/B: also read_registers through DIR's RtuLine")
    parser.add_argument("--served", action="store_true", help="also read_registers while the loop's thread runs")
    args = parser.parse_args()
    emulator = throughput.Emulator(0)
    server = throughput.start_server("pymodbus", emulator.server, BAUD, args.changing)
    try:
        throughput.wait_ready(emulator.client, BAUD)
        ops, closers = open_clients(emulator.client, args.watch_floor, args.before)
        turns: dict[str, Callable[[int, int], float]] = {name: partial(cpu_per_tx, op) for name, op in ops.items()}
        if args.served:
            turns["served"] = served_turn(ops["raw"])
        names = list(turns)
        samples: dict[str, list[float]] = {name: [] for name in names}
        try:
            for turn in range(args.rounds):
                shift = turn % len(names)
                for name in names[shift:] + names[:shift]:
                    samples[name].append(turns[name](args.tx, WARM))
        finally:
            for close in closers:
                close()
    finally:
        server.terminate()
        server.wait(timeout=10)
        emulator.close()
    report(samples, args)


def report(samples: dict[str, list[float]], args: argparse.Namespace) -> None:
    mean = {name: statistics.fmean(values) for name, values in samples.items()}
    print(
        f"FC03 x4 on a bare pty, {args.rounds} rounds x {args.tx} transactions per client"
        f"{', registers changing' if args.changing else ''}: CPU us per transaction (mean; median of the rounds)"
    )
    for name, values in samples.items():
        print(f"  {name:7s} {mean[name]:6.1f}  ({statistics.median(values):.1f})")
    floor = mean["floor"]
    print(
        f"  ratio to the floor: read_registers {mean['raw'] / floor:.2f}x   Device.read {mean['device'] / floor:.2f}x"
        "   (goals 1.2x, 1.5x)"
    )
    per_round = [(r / f, d / f) for f, r, d in zip(samples["floor"], samples["raw"], samples["device"], strict=True)]
    paired = [statistics.median(r for r, _ in per_round), statistics.median(d for _, d in per_round)]
    print(f"  median of the per-round ratios: read_registers {paired[0]:.2f}x   Device.read {paired[1]:.2f}x")
    if "before" in mean:
        ab = [r / b for r, b in zip(samples["raw"], samples["before"], strict=True)]
        print(
            f"  A/B: read_registers {mean['raw'] / mean['before']:.3f}x the --before tree's (paired "
            f"{statistics.median(ab):.3f}x); the --before tree's {mean['before'] / floor:.2f}x the floor"
        )
    if "served" in mean:
        ab = [s / r for s, r in zip(samples["served"], samples["raw"], strict=True)]
        print(
            f"  served (a ticket run by the loop's own thread): {mean['served'] / mean['raw']:.2f}x read_registers "
            f"in the caller's thread (paired {statistics.median(ab):.2f}x), {mean['served'] / floor:.2f}x the floor"
        )
    if "watch" in mean:
        watching = mean["watch"]
        print(
            f"  ratio to the watching floor ({watching / floor:.2f}x the floor): read_registers "
            f"{mean['raw'] / watching:.2f}x   Device.read {mean['device'] / watching:.2f}x"
        )


if __name__ == "__main__":
    main()
