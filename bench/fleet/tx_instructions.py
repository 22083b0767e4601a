"""Benchmark: the instructions a fleet transaction costs the poller's process, counted by valgrind (callgrind),
side by side with an older tree: a figure a busy machine does not move (timings on two shared cores do).

    python -m starterbus.bench.fleet.tx_instructions [--before DIR] [--devices 8] [--lines 1] [--tx 100 600]

``--lines`` Modbus RTU lines (each a bare pty hop: ``bench/modbus/line_emulator.py --baud 0``), ``--devices``
simulated starters on each in a process of their own (``rtu_scale.py serve``), polled by a ``FleetPoller`` back
to back (period 1 ms) until the poller has emitted the given number of good samples (several lines: what a turn
of the loop costs per driver it serves counts too, as on the 16 lines of ``rtu_scale.py``). The poller's process
runs under callgrind, twice (the two ``--tx`` counts); instructions per transaction = the difference / the
difference in transactions (start-up, imports and the end cancel out). The simulator and the emulator are not
counted. Each tree runs once natively first (its ``.pyc`` files written). Needs ``valgrind`` (Debian: ``apt-get
install valgrind``). ``--before DIR``: also the tree in DIR (a directory holding ``starterbus/``), and the ratio.

What it does not see: the kernel's share (system calls, context switches) and cache misses; the paced lines of
``rtu_scale.py`` wake the poller more often per transaction than a bare pty does.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

MODELS = ("jjr5000", "ssd1")


def poll(tx: int, devices: int, lines: int = 1) -> None:
    """The measured process: poll until ``tx`` good samples."""
    import starterbus
    from starterbus.bench.modbus.throughput import Emulator
    from starterbus.fleet.config import parse_fleet
    from starterbus.fleet.poller import FleetPoller

    rtu_scale = Path(starterbus.__file__).parent / "bench" / "fleet" / "rtu_scale.py"  # the measured tree's
    emulators = [Emulator(0) for _ in range(lines)]
    sims = subprocess.Popen(
        [sys.executable, str(rtu_scale), "serve", "--paths", *[e.server for e in emulators], "--counts"]
        + [str(devices)] * lines,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert sims.stdout is not None and sims.stdin is not None
    try:
        if sims.stdout.readline().strip() != "ready":
            raise RuntimeError("the simulator process did not start")
        text = "[poll]\nperiod = 0.001\n\n"
        for line, emulator in enumerate(emulators):
            url = f"modbus-rtu://{emulator.client}?baudrate=19200&timeout=1.0&retries=1"
            text += f'[[bus]]\nname = "l{line}"\nurl = "{url}"\n' + "".join(
                f'[[bus.device]]\nname = "d{line}-{u}"\nmodel = "{MODELS[u % 2]}"\naddress = {u}\n'
                for u in range(1, devices + 1)
            )
        done, good, bad = threading.Event(), [0], [0]

        def on_sample(sample: object) -> None:
            if getattr(sample, "online", False):
                good[0] += 1
            else:
                bad[0] += 1
            if good[0] >= tx:
                done.set()

        with FleetPoller(parse_fleet(text, "<tx_instructions>"), on_sample):
            if not done.wait(600):
                raise RuntimeError(f"only {good[0]} good samples in 600 s")
        print(f"samples {good[0]} errors {bad[0]}", flush=True)
    finally:
        sims.stdin.close()
        sims.wait(timeout=20)
        for emulator in emulators:
            emulator.close()


def environment(root: Path | None) -> dict[str, str]:
    """The measured process imports ``root``'s tree (None: this one); this script runs from this tree."""
    env = dict(os.environ)
    env["PYTHONHASHSEED"] = "0"  # the same sets and dicts at every start: start-ups that cancel out in the difference
    if root is not None:
        plugin = root / "starterbus" / "plugins" / "starterbus-canopen"
        env["PYTHONPATH"] = os.pathsep.join([str(root), str(plugin), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def command(tx: int, devices: int, lines: int = 1) -> list[str]:
    python = os.path.realpath(sys.executable)  # not a shim script: callgrind follows no child
    return [python, str(Path(__file__).resolve()), "--poll", str(tx), "--devices", str(devices), "--lines", str(lines)]


def instructions(root: Path | None, tx: int, devices: int, lines: int = 1) -> int:
    """Instructions of one measured process under callgrind."""
    return callgrind(command(tx, devices, lines), environment(root))


def callgrind(measured: list[str], env: dict[str, str]) -> int:
    """Instructions of the process ``measured`` runs, under callgrind (its children not counted)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run(
            ["valgrind", "--tool=callgrind", f"--callgrind-out-file={tmp}/cg.out", *measured],
            env=env,
            capture_output=True,
            text=True,
            check=True,
            cwd=tmp,
        )
    found = re.search(r"Collected : (\d+)", out.stderr)
    if found is None:
        raise RuntimeError(f"no count from callgrind: {out.stderr[-500:]}")
    return int(found.group(1))


def per_transaction(root: Path | None, counts: tuple[int, int], devices: int, lines: int = 1) -> float:
    env = environment(root)
    subprocess.run(command(5, devices, lines), env=env, check=True, capture_output=True)  # the .pyc files
    low, high = (instructions(root, n, devices, lines) for n in counts)
    return (high - low) / (counts[1] - counts[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", type=Path, help="also this tree (a directory holding starterbus/)")
    parser.add_argument("--devices", type=int, default=8, help="devices a line")
    parser.add_argument("--lines", type=int, default=1)
    parser.add_argument("--tx", type=int, nargs=2, default=(100, 600), metavar=("LOW", "HIGH"))
    parser.add_argument("--poll", type=int, help=argparse.SUPPRESS)  # the measured process
    args = parser.parse_args()
    if args.poll is not None:
        poll(args.poll, args.devices, args.lines)
        return
    if shutil.which("valgrind") is None:
        raise SystemExit("tx_instructions: valgrind is not installed (apt-get install valgrind)")
    counts = (args.tx[0], args.tx[1])
    after = per_transaction(None, counts, args.devices, args.lines)
    print(f"this tree: {after:,.0f} instructions a transaction", flush=True)
    if args.before is not None:
        before = per_transaction(args.before, counts, args.devices, args.lines)
        print(f"{args.before}: {before:,.0f} instructions a transaction")
        print(f"this tree / before: {after / before:.3f}x")


if __name__ == "__main__":
    main()
