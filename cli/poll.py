"""``starterbus poll FLEET.toml``: the live fleet table, JSON lines or a CSV log.

The fleet machinery is imported when the command runs, not when its options are built (``poll --help``).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TextIO

from starterbus.cli.arguments import record_args
from starterbus.cli.output import emit_json, table
from starterbus.fleet.probing import DEFAULT_PROBE_SHARE, DEFAULT_PROBE_TIMEOUT

if TYPE_CHECKING:
    from starterbus.core.supervision import Supervisor
    from starterbus.fleet.config import FleetConfig
    from starterbus.fleet.output import CsvLog, JsonLines
    from starterbus.fleet.plan import BusPlan
    from starterbus.fleet.poller import FleetPoller, Sample
    from starterbus.fleet.probing import ProbeSettings
    from starterbus.ops.recorder import HistoryRecorder


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("fleet", metavar="FLEET.toml", help="fleet file (see examples/fleet.toml)")
    p.add_argument("--once", action="store_true", help="poll every device once, print, exit")
    p.add_argument("--json", action="store_true", help="stream one JSON object per sample")
    p.add_argument(
        "--csv",
        metavar="FILE",
        help="append every sample to a CSV log (wide: a column per point, ISO 8601 UTC times); - = stdout",
    )
    p.add_argument("--csv-long", action="store_true", help="CSV in long format: one row per value")
    record_args(p, "write samples and events to this SQLite history (see `history`)")
    p.add_argument("--metrics", metavar="HOST:PORT", help="Prometheus endpoint (/metrics), e.g. 127.0.0.1:9477")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.add_argument("--refresh", type=float, default=0.5, help="table refresh period on a terminal, s")
    p.add_argument(
        "--plan", action="store_true", help="print each device's poll plan and each line's wire budget; send nothing"
    )
    p.add_argument(
        "--probe-timeout",
        type=float,
        default=DEFAULT_PROBE_TIMEOUT,
        metavar="S",
        help=f"answer timeout of a probe of an offline device (one attempt), s (default {DEFAULT_PROBE_TIMEOUT})",
    )
    p.add_argument(
        "--probe-share",
        type=float,
        default=DEFAULT_PROBE_SHARE,
        metavar="F",
        help=f"largest share of a line's time spent probing offline devices (default {DEFAULT_PROBE_SHARE})",
    )


_WIDTHS: dict[int, list[int]] = {}  # per output stream: the widest columns so far, so a live view never jumps


def render(poller: FleetPoller, out: TextIO, in_place: bool, banner: str = "") -> None:
    from starterbus.fleet.output import TABLE_HEADERS, table_rows_styled

    if in_place:
        out.write("\x1b[H\x1b[J")
    now = poller.clock()
    out.write(
        f"starterbus poll  {time.strftime('%H:%M:%S')}  devices {len(poller.runtimes())}  "
        f"transactions {poller.transactions()}\n"
    )
    styled = table_rows_styled(poller.runtimes(), now)
    _WIDTHS[id(out)] = table(
        TABLE_HEADERS, [r for r, _ in styled], out, widths=_WIDTHS.get(id(out)), styles=[s for _, s in styled]
    )
    for bus, stats in poller.line_stats().items():
        wire = stats.wire
        if wire.bytes_sent:
            counted = (
                f"{wire.requests} requests ({wire.retries} retries, {wire.timeouts} timeouts), "
                f"{wire.bytes_sent} B out, {wire.bytes_received} B in, wire {stats.wire_utilisation:.0%}"
            )
        else:
            counted = f"{wire.transactions} calls (its transport does not count frames)"
        out.write(f"line {bus}: {counted}, busy {stats.utilisation:.0%}, {stats.probes} probes\n")
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
    probing: ProbeSettings | None = None,
    csv_long: bool = False,
    recorder: HistoryRecorder | None = None,
    supervisor: Supervisor | None = None,
    metrics: str | None = None,
) -> int:
    """Poll a fleet and show it; shared by ``poll`` and ``demo``. Returns the exit code: 0 after the duration,
    a stop or the rounds asked for; 130 after Ctrl-C; a worker's fatal failure (or the poller ending by
    itself) raises :class:`~starterbus.core.supervision.ServiceFailed` once everything is shut down."""
    from starterbus.core.errors import ConfigurationError
    from starterbus.core.supervision import ServiceFailed
    from starterbus.fleet.health import notify_systemd
    from starterbus.fleet.output import CsvLog, JsonLines
    from starterbus.fleet.poller import FleetPoller

    out = out or sys.stdout
    sinks = list(sinks or [])
    if csv_path == "-" and json_out:
        raise ConfigurationError("--csv - and --json both write to standard output: give one of them")
    quiet = json_out or csv_path == "-"  # stdout carries the JSON or the CSV only: no table
    csv_log = CsvLog(csv_path, config, long=csv_long) if csv_path else None
    if csv_log is not None:
        sinks.append(csv_log)
    json_lines = JsonLines(out) if json_out else None
    if json_lines is not None:
        sinks.append(json_lines)
    if recorder is not None:
        sinks.insert(0, recorder)
        if json_lines is not None:
            recorder.writer.on_event = json_lines.event  # the history failing and recovering: event lines

    def on_sample(sample: Sample) -> None:
        failed: Exception | None = None
        for sink in sinks:  # one failing sink (a CSV on a full disk) keeps the sample from no other
            try:
                sink(sample)
            except Exception as exc:
                failed = failed or exc
        if failed is not None:
            raise failed  # the poller's supervisor: logged, counted, the bus resumes after a backoff

    poller = FleetPoller(config, on_sample, rounds=1 if once else None, probing=probing, supervisor=supervisor)
    in_place = out.isatty() and not quiet
    if metrics is not None:
        _serve_metrics(metrics, poller, recorder)
    terminated: list[int] = []
    previous = _on_sigterm(poller, terminated)
    poller.start()
    notify_systemd(poller)  # under systemd: READY=1 after the first round, WATCHDOG=1 while the polls progress
    interrupted = asked = False
    try:
        if during is not None:
            during(poller)
        deadline = None if duration is None else time.monotonic() + duration
        last_print = time.monotonic()
        while poller.running:
            if deadline is not None and time.monotonic() >= deadline:
                asked = True
                break
            if _reader_gone(json_lines, csv_log):  # the reader went away (`| head -1`)
                asked = True
                break
            poller.stopping.wait(refresh if in_place else 0.2)
            if in_place:
                render(poller, out, True, banner() if banner else "")
            elif not quiet and not once and time.monotonic() - last_print >= config.period:
                last_print = time.monotonic()  # on a pipe: one table per fleet period, not a redraw
                render(poller, out, False, banner() if banner else "")
                out.write("\n")
    except KeyboardInterrupt:
        interrupted = True
    finally:
        poller.stop()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        if csv_log is not None:
            csv_log.close()
    asked = asked or bool(terminated)
    if _reader_gone(json_lines, csv_log):
        raise BrokenPipeError("the reader went away")  # after the clean stop; `main` exits 0 quietly
    if not quiet:
        render(poller, out, in_place)
    poller.supervisor.check()  # a worker failed for good: one line, exit 1
    if interrupted:
        return 130  # Ctrl-C: after a clean shutdown, as every command
    if not asked and not once:  # every thread ended, and nobody asked for it (a defect): never a quiet exit 0
        raise ServiceFailed("the poller", RuntimeError("every polling thread ended by itself"))
    bad = [r for r in poller.runtimes() if not r.online]
    return 1 if once and bad else 0


def _on_sigterm(poller: FleetPoller, terminated: list[int]) -> signal.Handlers | Any | None:
    """SIGTERM (systemd's stop) stops the poller cleanly, as the duration does; returns the handler it replaced
    (None off the main thread, where signals cannot be caught)."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def on_term(signum: int, _frame: object) -> None:
        terminated.append(signum)
        poller.request_stop()

    return signal.signal(signal.SIGTERM, on_term)


def _serve_metrics(address: str, poller: FleetPoller, recorder: HistoryRecorder | None) -> None:
    """``--metrics``: the fleet's and the service's series (workers' failures, the history's writes)."""
    from starterbus.ops.service_metrics import ServiceCollector
    from starterbus.serve.prometheus import FleetCollector, start_metrics_server

    fleet = FleetCollector()
    fleet.poller = poller
    poller.on_sample = _also(poller.on_sample, fleet.observe)
    host, port, _server = start_metrics_server(
        address, fleet, ServiceCollector(poller.supervisor, recorder.writer if recorder else None)
    )
    print(f"Prometheus metrics: http://{host}:{port}/metrics", file=sys.stderr, flush=True)


def _also(first: Callable[[Sample], None] | None, then: Callable[[Sample], None]) -> Callable[[Sample], None]:
    def both(sample: Sample) -> None:
        if first is not None:
            first(sample)
        then(sample)

    return both


def _reader_gone(*sinks: JsonLines | CsvLog | None) -> bool:
    """The reader of the JSON or CSV on stdout went away (a closed pipe)."""
    return any(sink is not None and sink.closed for sink in sinks)


def _ms(seconds: float | None) -> str:
    return "?" if seconds is None else f"{seconds * 1000:.1f}"


def print_plan(plans: list[BusPlan], out: TextIO) -> None:
    for bus in plans:
        out.write(f"bus {bus.name}  {bus.url}\n")
        rows: list[list[object]] = []
        for device in bus.devices:
            rows.append([device.name, device.model, device.sent, device.registers, _ms(device.wire_time), ""])
            rows += [["", "", "", r.registers, _ms(r.wire_time), r.text] for r in device.requests]
        table(["device", "model", "requests", "registers", "wire ms", "request"], rows, out)
        if bus.wire_time is None or bus.load is None:
            out.write("line budget: unknown (the transport does not tell its wire time)\n\n")
            continue
        periods = sorted({d.period for d in bus.devices})
        period = f"{periods[0] * 1000:g} ms" if len(periods) == 1 else "the devices' periods"
        out.write(
            f"line budget: {_ms(bus.wire_time)} ms of wire per round vs {period}: {bus.load * 100:.1f} % of the line"
            f"{'  (OVER: the line cannot keep the periods)' if bus.load > 1 else ''}; "
            f"at most {bus.max_rounds_per_s:.1f} rounds/s\n\n"
        )


def cmd_poll(args: argparse.Namespace) -> int:
    from starterbus.core.errors import ConfigurationError
    from starterbus.fleet.config import load_fleet
    from starterbus.fleet.plan import fleet_plan
    from starterbus.fleet.probing import ProbeSettings

    config = load_fleet(args.fleet)
    if args.plan:
        plans = fleet_plan(config)
        if args.json:
            emit_json({"fleet": config.source, "buses": [p.as_json() for p in plans]})
        else:
            print_plan(plans, sys.stdout)
        return 0
    try:
        probing = ProbeSettings(args.probe_timeout, args.probe_share)
    except ValueError as exc:
        raise ConfigurationError(str(exc)) from None
    from starterbus.core.supervision import Supervisor
    from starterbus.ops.recorder import for_fleet as recorder_for_fleet

    supervisor = Supervisor()
    recorder = None
    if args.record:
        recorder = recorder_for_fleet(
            args.record, config, args.keep, backlog=args.record_backlog, supervisor=supervisor
        )
    try:
        return run_fleet(
            config,
            once=args.once,
            json_out=args.json,
            csv_path=args.csv,
            csv_long=args.csv_long,
            duration=args.duration,
            refresh=args.refresh,
            probing=probing,
            recorder=recorder,
            supervisor=supervisor,
            metrics=args.metrics,
        )
    finally:
        if recorder is not None:
            recorder.close()
