"""CPU and wall time of one CANopen SDO read (``Device.read`` of one parameter), per thread, before and after.

    python plugins/starterbus-canopen/bench/sdo_reads.py [--reads 2000] [--pairs 3] [--before DIR | --before-tree DIR]
    python plugins/starterbus-canopen/bench/sdo_reads.py --instructions [--before-tree DIR] [--count 1000]

Each run is a process of its own: the plugin's simulator in the same process on a fresh ``virtual`` channel,
one device (``heartbeat=100``), 50 reads not counted, then ``--reads`` reads; it prints the wall time and the
CPU of each thread per read (the process's threads: the caller, the scheduler's, the bus's reader, the
simulator's). ``--before DIR``: every pair also runs the plugin found in ``DIR`` (a directory holding an older
``starterbus_canopen``, e.g. ``git archive 6515d89 plugins/starterbus-canopen | tar -x -C /tmp/old`` then
``--before /tmp/old/plugins/starterbus-canopen``), alternating which runs first. ``--before-tree DIR``: the
whole older tree instead (a directory holding ``starterbus/``, its plugin in ``starterbus/plugins/starterbus-canopen``:
e.g. the tree before issue 29). Not run by the tests; on a shared machine, give the load average with the figures.

``--instructions``: the instructions one read costs the process (every thread, the simulator's included),
counted by valgrind's callgrind from the first counted read to the last (``callgrind_control --instr``), a figure
a busy machine does not move (CPU times on two shared cores do); the interpreter lock is handed over only where a
thread waits (a switch interval of 1 s: the forced hand-offs of a slowed-down process would be counted). It does
not see the kernel's share (system calls, thread switches). Needs ``valgrind``.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

#: set to 1 in the environment of a run under callgrind: instructions are counted during the reads only
COUNTING = "SDO_READS_COUNTING"


def measure(reads: int) -> str:
    """One run in this process: the figures as one line."""
    from starterbus_canopen.simulator import CanopenSimulator

    from starterbus.core import ManualClock, SimulatedStarter, get_profile, open_device

    def cpu() -> dict[str, float]:
        out: dict[str, float] = {}
        for thread in threading.enumerate():
            if thread.ident is not None:
                name = f"{thread.name} {thread.ident}"
                out[name] = time.clock_gettime(time.pthread_getcpuclockid(thread.ident))
        return out

    channel = f"sdo-bench-{os.getpid()}"
    starter = SimulatedStarter(get_profile("example_canopen_starter"), ManualClock(0.0))
    counting = os.environ.get(COUNTING) == "1"  # under callgrind: count the reads only
    tick = 3600.0 if counting else 0.005  # (the simulator's ticks: per read, 50 times more under callgrind)
    with CanopenSimulator(("virtual", channel), heartbeat_ms=0, tick=tick) as sim:
        sim.add_node(starter, 5)
        with open_device(f"canopen://virtual/{channel}?node=5&heartbeat=100", "example_canopen_starter") as device:
            for _ in range(50):
                device.read("current_limit")
            if counting:
                subprocess.run(["callgrind_control", "--instr=on", str(os.getpid())], check=True, capture_output=True)
            before, started = cpu(), time.perf_counter()
            for _ in range(reads):
                device.read("current_limit")
            after, ended = cpu(), time.perf_counter()
            if counting:
                subprocess.run(["callgrind_control", "--instr=off", str(os.getpid())], check=True, capture_output=True)
    threads = {name: (after[name] - before.get(name, 0.0)) / reads * 1e6 for name in after}
    total = sum(threads.values())
    parts = ", ".join(f"{name.rsplit(' ', 1)[0][:24]} {us:.0f}" for name, us in sorted(threads.items()) if us >= 1)
    return f"{(ended - started) / reads * 1e6:.0f} us wall, {total:.0f} us CPU per read ({parts})"


def environment(plugin: str | None, tree: str | None) -> dict[str, str]:
    """The measured process imports ``plugin`` (an older plugin on this tree) or ``tree`` (a whole older tree)."""
    env = dict(os.environ)
    paths = [plugin] if plugin is not None else []
    if tree is not None:
        paths = [tree, str(Path(tree) / "starterbus" / "plugins" / "starterbus-canopen")]
    if paths:
        env["PYTHONPATH"] = os.pathsep.join(p for p in (*paths, env.get("PYTHONPATH")) if p)
    return env


def run(reads: int, plugin: str | None, tree: str | None = None) -> str:
    command = [sys.executable, __file__, "--measure", "--reads", str(reads)]
    return subprocess.run(
        command, env=environment(plugin, tree), check=True, capture_output=True, text=True
    ).stdout.strip()


def instructions(reads: int, tree: str | None) -> int:
    """Instructions of ``reads`` reads (counted from the first to the last, every thread) under callgrind."""
    python = os.path.realpath(sys.executable)  # not a shim script: callgrind follows no child
    env = environment(None, tree)
    env[COUNTING] = "1"
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run(
            ["valgrind", "--tool=callgrind", "--instr-atstart=no", f"--callgrind-out-file={tmp}/cg.out", python,
             str(Path(__file__).resolve()), "--measure", "--reads", str(reads), "--switch-interval", "1"],
            env=env, capture_output=True, text=True, check=True, cwd=tmp,
        )  # fmt: skip
    found = re.search(r"Collected : (\d+)", out.stderr)
    if found is None:
        raise RuntimeError(f"no count from callgrind: {out.stderr[-500:]}")
    return int(found.group(1))


def per_read(reads: int, tree: str | None) -> float:
    run(5, None, tree)  # the .pyc files written first
    return instructions(reads, tree) / reads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--reads", type=int, default=2000)
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--before", metavar="DIR", help="a directory holding an older starterbus_canopen")
    parser.add_argument(
        "--before-tree", metavar="DIR", help="a directory holding an older starterbus/ (and its plugin)"
    )
    parser.add_argument("--instructions", action="store_true", help="count instructions per read under callgrind")
    parser.add_argument("--count", type=int, default=1000, help="reads counted under callgrind")
    parser.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--switch-interval", type=float, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        if args.switch_interval is not None:  # under callgrind: no forced hand-offs of the interpreter lock
            sys.setswitchinterval(args.switch_interval)
        print(measure(args.reads))
        return
    if args.instructions:
        after = per_read(args.count, None)
        print(f"this tree: {after:,.0f} instructions a read", flush=True)
        if args.before_tree is not None:
            before = per_read(args.count, args.before_tree)
            print(f"{args.before_tree}: {before:,.0f} instructions a read")
            print(f"this tree / before: {after / before:.3f}x")
        return
    older: list[tuple[str, str | None, str | None]] = [("before", args.before, None)] if args.before else []
    if args.before_tree:
        older = [("before", None, args.before_tree)]
    for pair in range(args.pairs):
        runs: list[tuple[str, str | None, str | None]] = [("after", None, None), *older]
        for label, plugin, tree in runs if pair % 2 == 0 else runs[::-1]:
            print(f"{label:6} {run(args.reads, plugin, tree)}", flush=True)
        print(f"       load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)


if __name__ == "__main__":
    main()
