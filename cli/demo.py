"""``starterbus demo``: the main job on an in-process simulated mixed fleet."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duration", type=float, default=20.0, help="seconds to run (default 20)")
    p.add_argument("--json", action="store_true", help="stream samples as JSON lines instead of the table")


def cmd_demo(args: argparse.Namespace) -> int:
    from starterbus.fleet.demo import run_demo

    return run_demo(duration=args.duration, json_out=args.json)
