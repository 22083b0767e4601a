"""``starterbus simulate``: serve simulated starters behind one or more protocol front ends."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from starterbus.core.errors import ConfigurationError
from starterbus.core.registry import get_profile, transports
from starterbus.core.simulator import SimulatedStarter
from starterbus.core.transport import RunningSimulator


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", required=True, help="device model (jjr5000, ssd1, jjr8000) or a profile .toml")
    parser.add_argument(
        "--unit",
        type=int,
        action="append",
        default=None,
        help="device address of a simulated starter (Modbus unit id); repeat for several on one line (default 1)",
    )
    parser.add_argument("--load", type=float, default=0.8, help="running current as a fraction of rated current")
    parser.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    for entry in transports.load_all():
        if entry.loaded is not None:
            group = parser.add_argument_group(f"{entry.name} front end")
            entry.loaded.add_simulator_arguments(group)  # type: ignore[arg-type]


def cmd_simulate(args: argparse.Namespace) -> int:
    profile = get_profile(args.model)
    units = args.unit or [1]
    if len(set(units)) != len(units):
        raise ConfigurationError(f"--unit given twice with the same address: {units}")
    starters = [SimulatedStarter(profile, load=args.load) for _ in units]
    args.unit = units
    running: list[RunningSimulator] = []
    try:
        for entry in transports.entries():
            if entry.loaded is not None:
                running.extend(entry.loaded.start_simulators(args, profile, starters))
        if not running:
            raise ConfigurationError("no front end asked for: give at least one of the protocol options (see --help)")
        for sim in running:
            for line in sim.describe():
                print(line, flush=True)
        stop = threading.Event()
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, lambda *_: stop.set())
        deadline = None if args.duration is None else time.monotonic() + args.duration
        try:
            while not stop.is_set():
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    break
                stop.wait(0.5 if remaining is None else min(0.5, remaining))
        except KeyboardInterrupt:
            print("stopped", file=sys.stderr)
    finally:
        for sim in running:
            sim.close()
    return 0
