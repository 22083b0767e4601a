"""CPU and wall time of one CANopen SDO read (``Device.read`` of one parameter), per thread, before and after.

    python plugins/starterbus-canopen/bench/sdo_reads.py [--reads 2000] [--pairs 3] [--before DIR]

Each run is a process of its own: the plugin's simulator in the same process on a fresh ``virtual`` channel,
one device (``heartbeat=100``), 50 reads not counted, then ``--reads`` reads; it prints the wall time and the
CPU of each thread per read (the process's threads: the caller, the scheduler's, the bus's reader, the
simulator's). ``--before DIR``: every pair also runs the plugin found in ``DIR`` (a directory holding an older
``starterbus_canopen``, e.g. ``git archive 6515d89 plugins/starterbus-canopen | tar -x -C /tmp/old`` then
``--before /tmp/old/plugins/starterbus-canopen``), alternating which runs first. Not run by the tests; on a
shared machine, give the load average with the figures.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time


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
    with CanopenSimulator(("virtual", channel), heartbeat_ms=0) as sim:
        sim.add_node(starter, 5)
        with open_device(f"canopen://virtual/{channel}?node=5&heartbeat=100", "example_canopen_starter") as device:
            for _ in range(50):
                device.read("current_limit")
            before, started = cpu(), time.perf_counter()
            for _ in range(reads):
                device.read("current_limit")
            after, ended = cpu(), time.perf_counter()
    threads = {name: (after[name] - before.get(name, 0.0)) / reads * 1e6 for name in after}
    total = sum(threads.values())
    parts = ", ".join(f"{name.rsplit(' ', 1)[0][:24]} {us:.0f}" for name, us in sorted(threads.items()) if us >= 1)
    return f"{(ended - started) / reads * 1e6:.0f} us wall, {total:.0f} us CPU per read ({parts})"


def run(reads: int, plugin: str | None) -> str:
    env = dict(os.environ)
    if plugin is not None:
        env["PYTHONPATH"] = os.pathsep.join(p for p in (plugin, env.get("PYTHONPATH")) if p)
    command = [sys.executable, __file__, "--measure", "--reads", str(reads)]
    return subprocess.run(command, env=env, check=True, capture_output=True, text=True).stdout.strip()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--reads", type=int, default=2000)
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--before", metavar="DIR", help="a directory holding an older starterbus_canopen")
    parser.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        print(measure(args.reads))
        return
    for pair in range(args.pairs):
        runs = [("after", None)] + ([("before", args.before)] if args.before else [])
        for label, plugin in runs if pair % 2 == 0 else runs[::-1]:
            print(f"{label:6} {run(args.reads, plugin)}", flush=True)
        print(f"       load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)


if __name__ == "__main__":
    main()
