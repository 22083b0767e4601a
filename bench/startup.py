"""Benchmark: start-up of the ``starterbus`` command against ``python -c pass``, as ratios.

Run: ``python bench/startup.py [--runs 20]``

Each command runs ``--runs`` times, alternating with the baseline so that both see the same machine; the
median wall time of each is printed with its ratio to the baseline's median. The commands run through the
interpreter of this process (``python -m starterbus.cli.main ...`` is what the ``starterbus`` script does).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

COMMANDS: list[tuple[str, list[str]]] = [
    ("starterbus --help", ["-c", "from starterbus.cli.main import main; main(['--help'])"]),
    ("starterbus poll --help", ["-c", "from starterbus.cli.main import main; main(['poll', '--help'])"]),
    ("starterbus models", ["-c", "from starterbus.cli.main import main; main(['models'])"]),
    ("import starterbus", ["-c", "import starterbus"]),
]
BASELINE = ["-c", "pass"]


def once(args: list[str]) -> float:
    started = time.perf_counter()
    subprocess.run([sys.executable, *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    args = parser.parse_args()
    once(BASELINE)  # warm the file cache
    print(f"{'command':<24} {'median ms':>9} {'python -c pass':>14} {'ratio':>6}")
    for name, command in COMMANDS:
        once(command)
        mine, base = [], []
        for _ in range(args.runs):
            base.append(once(BASELINE))
            mine.append(once(command))
        m, b = statistics.median(mine), statistics.median(base)
        print(f"{name:<24} {m * 1000:>9.1f} {b * 1000:>14.1f} {m / b:>6.2f}")


if __name__ == "__main__":
    main()
