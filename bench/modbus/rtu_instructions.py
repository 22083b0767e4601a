"""Benchmark: the instructions one Modbus RTU ``read_registers`` costs its caller, counted by valgrind
(callgrind), beside the hand-written floor of ``cpu_floor.py`` and an older tree: figures a busy machine does not
move (CPU timings on two shared cores do).

    python -m starterbus.bench.modbus.rtu_instructions [--before DIR] [--reads 200 1200]

The caller's own transaction (``RtuLine.run`` in the calling thread, no loop thread: the leader's path), FC03 of
four registers at unit 2 on a bare pty hop (``line_emulator.py --baud 0``) to a simulated starter in a process of
its own (``bench/fleet/rtu_scale.py serve``). The measured process runs under callgrind twice (the two
``--reads`` counts); instructions a read = the difference / the difference in reads (start-up, imports and the
end cancel out). ``floor``: the same reads by ``clients.exact_ops`` (write, ``select``, read exactly the
predicted length, the silence slept out before the next request), as ``cpu_floor.py`` measures it. The
simulator and the emulator are not counted. ``--before DIR``: also ``read_registers`` of the tree in DIR (a
directory holding ``starterbus/``), and the ratio. Needs ``valgrind``.

What it does not see: the kernel's share (system calls, context switches) and cache misses, which
``cpu_floor.py`` includes: its ratios to the floor are lower than these.
"""

from __future__ import annotations

import argparse
import gc
import os
import shutil
import subprocess
import sys
from pathlib import Path

WARM = 20  # reads before the counted ones (the first request, caches)
#: the line's nominal speed: its character time is how long input found empty counts as looked at before a send;
#: at 19200 baud (0.57 ms) a process slowed down by callgrind often outlives it between an answer and the next
#: request and looks again (a path that depends on the machine's load), at 2400 baud (4.6 ms) it does not
BAUD = 2400


def read(reads: int, client: str, baud: int = BAUD) -> None:
    """The measured process: ``reads`` FC03 reads by ``client`` (``raw``: starterbus, ``floor``)."""
    import starterbus
    from starterbus.bench.modbus import clients
    from starterbus.bench.modbus.throughput import Emulator

    rtu_scale = Path(starterbus.__file__).parent / "bench" / "fleet" / "rtu_scale.py"  # the measured tree's
    emulator = Emulator(0)
    sims = subprocess.Popen(
        [sys.executable, str(rtu_scale), "serve", "--paths", emulator.server, "--counts", str(clients.UNIT)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert sims.stdout is not None and sims.stdin is not None
    try:
        if sims.stdout.readline().strip() != "ready":
            raise RuntimeError("the simulator process did not start")
        if client == "raw":
            op, close = clients.starterbus_ops(emulator.client, baud, "fc03", False)
        else:
            op, close = clients.exact_ops(emulator.client, baud, "fc03", True)
        try:
            for _ in range(WARM):
                op()
            gc.collect()
            gc.freeze()  # what start-up left is not scanned again by the reads' collections (nor counted)
            for _ in range(reads):
                op()
        finally:
            close()
    finally:
        sims.stdin.close()
        sims.wait(timeout=20)
        emulator.close()


def command(reads: int, client: str, baud: int = BAUD) -> list[str]:
    python = os.path.realpath(sys.executable)  # not a shim script: callgrind follows no child
    return [python, str(Path(__file__).resolve()), "--read", str(reads), "--client", client, "--baud", str(baud)]


def per_read(root: Path | None, counts: tuple[int, int], client: str, baud: int = BAUD) -> float:
    from starterbus.bench.fleet.tx_instructions import callgrind, environment  # (not in the measured process: an
    # older tree's may lack them)

    env = environment(root)
    subprocess.run(command(5, client, baud), env=env, check=True, capture_output=True)  # the .pyc files
    low, high = (callgrind(command(n, client, baud), env) for n in counts)
    return (high - low) / (counts[1] - counts[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", type=Path, help="also this tree (a directory holding starterbus/)")
    parser.add_argument("--reads", type=int, nargs=2, default=(200, 1200), metavar=("LOW", "HIGH"))
    parser.add_argument("--baud", type=int, default=BAUD, help="the line's nominal speed (default %(default)s)")
    parser.add_argument("--read", type=int, help=argparse.SUPPRESS)  # the measured process
    parser.add_argument("--client", choices=("raw", "floor"), default="raw", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.read is not None:
        read(args.read, args.client, args.baud)
        return
    if shutil.which("valgrind") is None:
        raise SystemExit("rtu_instructions: valgrind is not installed (apt-get install valgrind)")
    counts = (args.reads[0], args.reads[1])
    floor = per_read(None, counts, "floor", args.baud)
    print(f"floor: {floor:,.0f} instructions a read", flush=True)
    after = per_read(None, counts, "raw", args.baud)
    print(f"this tree: {after:,.0f} instructions a read_registers ({after / floor:.2f}x the floor)", flush=True)
    if args.before is not None:
        before = per_read(args.before, counts, "raw", args.baud)
        print(f"{args.before}: {before:,.0f} instructions a read_registers ({before / floor:.2f}x the floor)")
        print(f"this tree / before: {after / before:.3f}x")


if __name__ == "__main__":
    main()
