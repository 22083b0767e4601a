"""``starterbus poll FLEET.toml``: the live fleet table, JSON lines or a CSV log."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from typing import TextIO

from starterbus.cli.output import table
from starterbus.fleet.config import FleetConfig, load_fleet
from starterbus.fleet.output import TABLE_HEADERS, CsvLog, JsonLines, table_rows
from starterbus.fleet.poller import FleetPoller, Sample
from starterbus.ops.recorder import for_fleet as recorder_for_fleet


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("fleet", metavar="FLEET.toml", help="fleet file (see examples/fleet.toml)")
    p.add_argument("--once", action="store_true", help="poll every device once, print, exit")
    p.add_argument("--json", action="store_true", help="stream one JSON object per sample")
    p.add_argument("--csv", metavar="FILE", help="append every sample to a CSV log")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.add_argument("--refresh", type=float, default=0.5, help="table refresh period on a terminal, s")
    p.add_argument("--record", metavar="DB", help="write samples and events to this SQLite history (see `history`)")
    p.add_argument("--keep", action="append", metavar="AGE|SIZE", help="history retention: 30d, 12h, 500MB")


def render(poller: FleetPoller, out: TextIO, in_place: bool, banner: str = "") -> None:
    if in_place:
        out.write("\x1b[H\x1b[J")
    now = poller.clock()
    out.write(
        f"starterbus poll  {time.strftime('%H:%M:%S')}  devices {len(poller.runtimes())}  "
        f"transactions {poller.transactions()}\n"
    )
    table(TABLE_HEADERS, table_rows(poller.runtimes(), now), out)
    if banner:
        out.write(banner + "\n")
    out.flush()


def run_fleet(
    config: FleetConfig,
    *,
    once: bool,
    json_out: bool,
    csv_path: str | None,
    duration: float | None,
    refresh: float = 0.5,
    out: TextIO | None = None,
    during: Callable[[FleetPoller], None] | None = None,
    sinks: list[Callable[[Sample], None]] | None = None,
    banner: Callable[[], str] | None = None,
) -> int:
    """Poll a fleet and show it; shared by ``poll`` and ``demo``. Returns the exit code."""
    out = out or sys.stdout
    sinks = list(sinks or [])
    csv_log = CsvLog(csv_path) if csv_path else None
    if csv_log is not None:
        sinks.append(csv_log)
    if json_out:
        sinks.append(JsonLines(out))

    def on_sample(sample: Sample) -> None:
        for sink in sinks:
            sink(sample)

    poller = FleetPoller(config, on_sample, rounds=1 if once else None)
    in_place = out.isatty() and not json_out
    poller.start()
    try:
        if during is not None:
            during(poller)
        deadline = None if duration is None else time.monotonic() + duration
        last_print = time.monotonic()
        while poller.running:
            if deadline is not None and time.monotonic() >= deadline:
                break
            poller.stopping.wait(refresh if in_place else 0.2)
            if in_place:
                render(poller, out, True, banner() if banner else "")
            elif not json_out and not once and time.monotonic() - last_print >= config.period:
                last_print = time.monotonic()  # on a pipe: one table per fleet period, not a redraw
                render(poller, out, False, banner() if banner else "")
                out.write("\n")
    except KeyboardInterrupt:
        pass
    finally:
        poller.stop()
        if csv_log is not None:
            csv_log.close()
    if not json_out:
        render(poller, out, in_place)
    bad = [r for r in poller.runtimes() if not r.online]
    return 1 if once and bad else 0


def cmd_poll(args: argparse.Namespace) -> int:
    config = load_fleet(args.fleet)
    recorder = recorder_for_fleet(args.record, config, args.keep) if args.record else None
    try:
        return run_fleet(
            config,
            once=args.once,
            json_out=args.json,
            csv_path=args.csv,
            duration=args.duration,
            refresh=args.refresh,
            sinks=[recorder] if recorder is not None else None,
        )
    finally:
        if recorder is not None:
            recorder.close()
