"""Run pkw_reads.py on this tree and on a baseline tree side by side, interleaved, and print the ratios.

    python bench/profibus/compare.py BASELINE_DIR [--rounds 5] [--seconds 0.5]

``BASELINE_DIR`` holds a checkout of another commit as a package named ``starterbus`` (for example
``git archive COMMIT | tar -x -C /tmp/base/src && ln -s /tmp/base/src /tmp/base/starterbus``, then pass
``/tmp/base``). Each round runs the baseline and then this tree; the best reads/s of each row over the rounds is
kept (the least disturbed run on a shared machine), and the ratio is this tree / baseline.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
BENCH = HERE / "pkw_reads.py"


def run(pythonpath: str | None, seconds: float) -> dict[tuple[str, str, str], float]:
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    out = subprocess.run(
        [sys.executable, str(BENCH), "--seconds", str(seconds), "--json"],
        env=env,
        cwd="/",
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return {(r["channel"], r["cycle"], r["level"]): float(r["per_second"]) for r in json.loads(out)["rows"]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("baseline", help="directory holding the baseline tree as 'starterbus'")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=0.5)
    args = parser.parse_args(argv)
    best: dict[str, dict[tuple[str, str, str], float]] = {"base": {}, "this": {}}
    for _ in range(args.rounds):
        for name, path in (("base", args.baseline), ("this", None)):
            for key, value in run(path, args.seconds).items():
                best[name][key] = max(best[name].get(key, 0.0), value)
    print(f"best of {args.rounds} interleaved rounds, {args.seconds:g} s per row; ratio = this / baseline")
    print(f"{'channel':8} {'cycle s':>8} {'level':7} {'base/s':>10} {'this/s':>10} {'ratio':>6}")
    for key, value in best["this"].items():
        base = best["base"].get(key)
        ratio = f"{value / base:.2f}" if base else "-"
        print(f"{key[0]:8} {key[1]:>8} {key[2]:7} {base or '-':>10} {value:>10} {ratio:>6}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
