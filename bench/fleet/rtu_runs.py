"""Benchmark: ``rtu_scale.py`` run again and again (each run with ``--floor``, in a process of its own), and what the
runs say together against issue 29's goals: the poller under 0.20 of a core, the slowest line within 2 % of what the
rig alone reaches in the same run.

    python bench/fleet/rtu_runs.py [--runs 5] [--size 992] [--seconds 20] [--emulators-on CPU]
                                   [--before-python PY] [--json FILE]

One run's figure moves with the rig (how often its real-time emulator threads preempt the poller: see
``rig.py``), by about +-10 % on two shared cores; the median over several runs, and how many runs meet each goal,
are the figures to compare. ``--before-python PY``: a Python whose ``starterbus`` is an older tree, installed
with its bench (``python -m venv V && V/bin/pip install OLD && cp -r OLD/bench V/lib/python3.*/site-packages/
starterbus/``): its ``rtu_scale`` runs before each of this tree's, alternating, and the ratios of the pairs are
printed. ``--emulators-on`` goes to this tree's runs alone (older benches may not have it). Not run by the tests.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

RTU_SCALE = Path(__file__).with_name("rtu_scale.py")
CPU_GOAL = 0.20  # of a core
LINE_GOAL = -0.02  # the slowest line against the rig alone


@dataclass(frozen=True)
class Run:
    tree: str  # "this" or "before"
    cpu: float  # the poller's CPU, share of one core
    us_per_transaction: float
    slowest_line: float  # of its plan's limit
    rig_alone: float  # the slowest line of the same run's --floor, of the wire limit
    preempted: float | None  # times a transaction (None: an older bench that does not count them)

    @property
    def line_gap(self) -> float:
        """The slowest line against the rig alone: -0.02 is 2 % below it."""
        return self.slowest_line / self.rig_alone - 1.0


def run_of(tree: str, result: dict[str, object]) -> Run:
    """One ``rtu_scale --json`` result (its poller run, with ``--floor``) as a :class:`Run`."""
    lines = result["per_line"]
    assert isinstance(lines, list)
    alone = [line["direct_of_wire_limit"] for line in lines if line["direct_of_wire_limit"] is not None]
    if not alone:
        raise SystemExit("rtu_runs: a run without the rig alone (rtu_scale.py ran without --floor)")
    preempted = result.get("preempted_per_transaction")
    return Run(
        tree,
        float(result["poller_cpu_cores"]),  # type: ignore[arg-type]
        float(result["cpu_per_transaction_us"]),  # type: ignore[arg-type]
        min(float(line["of_limit"]) for line in lines),
        min(float(value) for value in alone),
        None if preempted is None else float(preempted),  # type: ignore[arg-type]
    )


def measure(command: list[str], tree: str) -> Run:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run.json"
        done = subprocess.run([*command, "--json", str(out)], cwd=tmp, capture_output=True, text=True, check=False)
        if done.returncode != 0 or not out.exists():
            raise SystemExit(f"rtu_runs: {' '.join(command)} failed: {done.stderr.strip()[-400:]}")
        (result,) = json.loads(out.read_text(encoding="utf-8"))
    return run_of(tree, result)


def show(run: Run) -> str:
    preempted = "" if run.preempted is None else f", preempted {run.preempted:.2f} times a transaction"
    return (
        f"{run.tree:<6} poller {run.cpu:.3f} of a core ({run.us_per_transaction:.0f} us a transaction){preempted}; "
        f"slowest line {run.slowest_line:.3f}, the rig alone {run.rig_alone:.3f} ({run.line_gap * 100:+.1f} %)"
    )


def summary(runs: list[Run], tree: str) -> str:
    mine = [r for r in runs if r.tree == tree]
    cpus = sorted(r.cpu for r in mine)
    gaps = [r.line_gap for r in mine]
    return (
        f"{tree}: {len(mine)} runs, poller {cpus[0]:.3f}-{cpus[-1]:.3f} of a core, "
        f"median {statistics.median(cpus):.3f}, "
        f"{sum(c < CPU_GOAL for c in cpus)} under {CPU_GOAL:.2f}; slowest line {min(gaps) * 100:+.1f} % to "
        f"{max(gaps) * 100:+.1f} % of the rig alone, {sum(g >= LINE_GOAL for g in gaps)} within {-LINE_GOAL:.0%}"
    )


def pairs(runs: list[Run]) -> str:
    before = [r for r in runs if r.tree == "before"]
    this = [r for r in runs if r.tree == "this"]
    ratios = [t.cpu / b.cpu for b, t in zip(before, this, strict=True)]
    return (
        f"this / before, run by run: {' '.join(f'{x:.2f}x' for x in ratios)}; medians "
        f"{statistics.median(r.cpu for r in this) / statistics.median(r.cpu for r in before):.2f}x"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5, help="runs of each tree")
    parser.add_argument("--size", type=int, default=992, help="devices (on 16 lines)")
    parser.add_argument("--seconds", type=float, default=20.0, help="each run's window")
    parser.add_argument("--emulators-on", type=int, metavar="CPU", help="this tree's runs: every emulator on CPU")
    parser.add_argument("--before-python", metavar="PY", help="a Python whose starterbus is an older tree")
    parser.add_argument("--json", metavar="FILE", help="also write every run as JSON")
    args = parser.parse_args()
    common = ["--sizes", str(args.size), "--seconds", str(args.seconds), "--floor"]
    this = [sys.executable, str(RTU_SCALE), *common]
    if args.emulators_on is not None:
        this += ["--emulators-on", str(args.emulators_on)]
    runs: list[Run] = []
    for _ in range(args.runs):
        if args.before_python:
            runs.append(measure([args.before_python, "-m", "starterbus.bench.fleet.rtu_scale", *common], "before"))
            print(show(runs[-1]), flush=True)
        runs.append(measure(this, "this"))
        print(show(runs[-1]), flush=True)
    print(summary(runs, "this"))
    if args.before_python:
        print(summary(runs, "before"))
        print(pairs(runs))
    if args.json:
        Path(args.json).write_text(json.dumps([asdict(r) for r in runs], indent=2), encoding="utf-8")


if __name__ == "__main__":
    main()
