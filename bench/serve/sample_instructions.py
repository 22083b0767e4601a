"""Benchmark: the instructions a sample costs ``serve`` (driver, session, encoding, paho's publish and write into
a local mosquitto), counted by valgrind (callgrind), side by side with an older tree: a figure a busy machine does
not move (timings on two shared cores do).

    python bench/serve/sample_instructions.py [--before DIR] [--after DIR] [--devices 1000] [--samples 1000 3000]

The load of ``bench/serve/throughput.py``: ``--devices`` JJR5000s of 10 metrics, every value changed since the
device's last sample, so every sample is a DDATA of 10 metrics; 5 samples a turn of the event loop (a 5 ms slot
of that bench). ``EdgeNodeDriver.run`` connects to mosquitto, the NBIRTH goes out at once, the first round of
samples makes the DBIRTHs, then the measured samples follow: nothing waits by the clock (a loop that polls
would count more instructions on a slower, busier machine). The process runs under
callgrind twice (the two ``--samples`` counts, every sample built before either is fed in); instructions a
sample = the difference / the difference in samples (start-up, imports, the births and the stop cancel out).
mosquitto is not counted. Each tree runs once natively first (its ``.pyc`` files written). Needs ``valgrind``
and ``mosquitto``. ``--before DIR``: also the tree in DIR (a directory holding ``starterbus/``), and the ratio;
``--after DIR``: that tree instead of the one installed.

What it does not see: the kernel's share (the ``send`` system calls, wake-ups) and cache misses.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

ROUNDS = 4  # samples built: the first round (the births), then up to 3 rounds of every device


class _Source:
    """A stand-in for the fleet: once ``go`` is set, the first round (the DBIRTHs), then ``count`` more samples,
    5 a turn; ``mark`` is called between the two."""

    def __init__(self, first: list[Any], rest: list[Any], count: int, mark: Callable[[], None]) -> None:
        self.first, self.rest, self.count, self.mark = first, rest, count, mark
        self.go = asyncio.Event()
        self.done = asyncio.Event()

    def subscribe(self) -> _Source:
        return self

    def __aiter__(self) -> AsyncIterator[Any]:
        return self._samples()

    async def _samples(self) -> AsyncIterator[Any]:
        await self.go.wait()
        for i in range(0, len(self.first), 5):
            for sample in self.first[i : i + 5]:
                yield sample
            await asyncio.sleep(0)
        self.mark()
        for i in range(0, self.count, 5):
            for sample in self.rest[i : min(i + 5, self.count)]:
                yield sample
            await asyncio.sleep(0)
        self.done.set()
        await asyncio.Event().wait()

    def drain(self) -> list[Any]:
        return []

    def close(self) -> None:
        pass


def measure(count: int, devices: int, port: int) -> None:
    """The measured process: ``count`` samples through the driver of the tree on ``PYTHONPATH``."""
    import time
    from typing import cast

    from starterbus.aio import AsyncFleet
    from starterbus.core.model import Value
    from starterbus.core.registry import get_profile
    from starterbus.core.status import decode_status_word
    from starterbus.fleet.config import DeviceConfig
    from starterbus.fleet.poller import Sample
    from starterbus.serve.broker import BrokerOptions
    from starterbus.serve.driver import EdgeNodeDriver
    from starterbus.serve.metrics import Aliases, device_metrics, node_metrics
    from starterbus.serve.session import EdgeSession, SessionOptions

    profile = get_profile("jjr5000")
    points = [p for p in profile.measurements if p.enum is None and p.key not in ("control_word", "status_word")]
    points += [p for p in profile.parameters if p.enum is None and p.raw_max - p.raw_min > 100]
    points = points[:10]
    meas = tuple(p.key for p in points if p in profile.measurements)
    params = tuple(p.key for p in points if p not in profile.measurements)
    configs = [DeviceConfig(f"d{i:04d}", "l1", "jjr5000", "synthetic", i, 1.0, meas, params) for i in range(devices)]
    status = decode_status_word(0x2200, profile.faults)  # running, ready
    t0 = time.time()

    def sample(config: DeviceConfig, round_: int) -> Any:
        values = {}
        for j, p in enumerate(points):
            raw = p.raw_min + (config.address or 0) + j + round_
            values[p.key] = Value.from_raw(p, min(raw, p.raw_max))
        return Sample(config.name, "l1", "jjr5000", t0 + round_, True, status, values, None, 0)

    rounds = [[sample(c, r) for c in configs] for r in range(ROUNDS)]
    rest = [s for r in rounds[1:] for s in r]
    if count > len(rest):
        raise SystemExit(f"at most {len(rest)} samples with {devices} devices")
    published = [0]
    aliases = Aliases()
    node = node_metrics(aliases)
    metrics = {c.name: device_metrics(c, profile, aliases) for c in configs}
    # the NBIRTH at once: each device's first sample makes its DBIRTH, none is stored and sent as history
    session = EdgeSession(SessionOptions("bench", "node1", refresh=0, first_round_wait=0), node, metrics)
    source = _Source(rounds[0], rest, count, lambda: published.__setitem__(0, session.published))
    connected = session.on_connected

    def on_connected(now: float) -> list[Any]:  # the samples start with the session: nothing waits by the clock
        actions = connected(now)
        source.go.set()
        return actions

    session.on_connected = on_connected  # type: ignore[method-assign]

    async def run() -> None:
        broker = BrokerOptions("127.0.0.1", port, keepalive=600)  # the births of 1000 devices take long in valgrind
        driver = EdgeNodeDriver(cast(AsyncFleet, source), session, broker)
        stop = asyncio.Event()
        task = asyncio.create_task(driver.run(stop))
        await source.done.wait()
        stop.set()
        await task
        if session.published - published[0] != count:
            raise SystemExit(f"{session.published - published[0]} DDATA published for {count} samples")

    asyncio.run(run())
    print(f"published {count}", flush=True)


def environment(root: Path | None) -> dict[str, str]:
    """The measured process imports ``root``'s tree (None: this one)."""
    env = dict(os.environ, PYTHONHASHSEED="0")
    if root is not None:
        plugin = root / "starterbus" / "plugins" / "starterbus-canopen"
        env["PYTHONPATH"] = os.pathsep.join([str(root), str(plugin), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def command(count: int, devices: int, port: int) -> list[str]:
    python = os.path.realpath(sys.executable)  # not a shim script: callgrind follows no child
    script = str(Path(__file__).resolve())
    return [python, script, "--measure", str(count), "--devices", str(devices), "--port", str(port)]


def instructions(root: Path | None, count: int, devices: int, port: int) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run(
            ["valgrind", "--tool=callgrind", f"--callgrind-out-file={tmp}/cg.out", *command(count, devices, port)],
            env=environment(root),
            capture_output=True,
            text=True,
            cwd=tmp,
            check=False,
        )
    found = re.search(r"Collected : (\d+)", out.stderr)
    if out.returncode != 0 or found is None:
        raise RuntimeError(f"callgrind run failed: {out.stdout[-300:]} {out.stderr[-800:]}")
    return int(found.group(1))


def per_sample(root: Path | None, counts: tuple[int, int], devices: int, port: int) -> float:
    subprocess.run(command(5, devices, port), env=environment(root), check=True, capture_output=True)  # .pyc files
    low, high = (instructions(root, n, devices, port) for n in counts)
    return (high - low) / (counts[1] - counts[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--before", type=Path, help="also this tree (a directory holding starterbus/)")
    parser.add_argument("--after", type=Path, help="this tree instead of the one installed (as --before)")
    parser.add_argument("--devices", type=int, default=1000)
    parser.add_argument("--samples", type=int, nargs=2, default=(1000, 3000), metavar=("LOW", "HIGH"))
    parser.add_argument("--measure", type=int, help=argparse.SUPPRESS)  # the measured process
    parser.add_argument("--port", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure is not None:
        measure(args.measure, args.devices, args.port)
        return
    for tool in ("valgrind", "mosquitto"):
        if shutil.which(tool) is None and not (tool == "mosquitto" and Path("/usr/sbin/mosquitto").exists()):
            raise SystemExit(f"sample_instructions: {tool} is not installed")
    from starterbus.serve.embedded import start_mosquitto

    broker = start_mosquitto()
    try:
        counts = (args.samples[0], args.samples[1])
        after = per_sample(args.after, counts, args.devices, broker.port)
        print(f"{args.after or 'this tree'}: {after:,.0f} instructions a sample", flush=True)
        if args.before is not None:
            before = per_sample(args.before, counts, args.devices, broker.port)
            print(f"{args.before}: {before:,.0f} instructions a sample")
            print(f"this tree / before: {after / before:.3f}x")
    finally:
        broker.close()


if __name__ == "__main__":
    main()
