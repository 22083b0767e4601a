"""``starterbus demo``: the main job on an in-process simulated mixed fleet (``fleet/demo.py``), polled by the
same code as ``starterbus poll`` while a scripted scenario runs, then a summary of the states each device went
through."""

from __future__ import annotations

import argparse
import sys
import threading
import time
from typing import TextIO

from starterbus.cli.poll import run_fleet
from starterbus.fleet.demo import demo_fleet, scenario
from starterbus.fleet.output import display_state
from starterbus.fleet.poller import FleetPoller, Sample


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duration", type=float, default=20.0, help="seconds to run (default 20)")
    p.add_argument("--json", action="store_true", help="stream samples as JSON lines instead of the table")


def cmd_demo(args: argparse.Namespace) -> int:
    return run_demo(duration=args.duration, json_out=args.json)


def run_demo(duration: float = 20.0, json_out: bool = False, out: TextIO | None = None) -> int:
    """Start the demo fleet, poll it with the live table while the scenario runs, then print a summary."""
    stream = out if out is not None else sys.stdout
    events: list[str] = []
    seen: dict[str, list[str]] = {}

    def track(sample: Sample) -> None:
        state = "offline" if not sample.online else (display_state(sample.status) if sample.status else "error")
        states = seen.setdefault(sample.device, [])
        if not states or states[-1] != state:
            states.append(state)

    with demo_fleet() as fleet:
        start = time.monotonic()

        def script(poller: FleetPoller) -> None:
            def run() -> None:
                for at, what, action in scenario(duration):
                    if poller.stopping.wait(max(0.0, start + at - time.monotonic())):
                        return
                    action(poller, fleet)
                    events.append(f"{time.monotonic() - start:5.1f}s  {what}")

            threading.Thread(target=run, name="demo-scenario", daemon=True).start()

        code = run_fleet(
            fleet.config,
            once=False,
            json_out=json_out,
            csv_path=None,
            duration=duration,
            out=stream,
            during=script,
            sinks=[track],
            banner=lambda: f"last event: {events[-1].strip()}" if events else "",
        )
    print_summary(sys.stderr if json_out else stream, events, seen)  # --json: stdout carries JSON only
    return code


def print_summary(out: TextIO, events: list[str], seen: dict[str, list[str]]) -> None:
    out.write("\nscenario:\n")
    for line in events:
        out.write(f"  {line}\n")
    out.write("states seen per device:\n")
    for device, states in seen.items():
        out.write(f"  {device:9} {' -> '.join(states)}\n")
