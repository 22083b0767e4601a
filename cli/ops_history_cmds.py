"""``history DB``, ``record URL --model M -o DIR``, ``plot DB --device D --event N``."""

from __future__ import annotations

import argparse
import csv
import re
import shlex
import sys
import time
from datetime import datetime
from pathlib import Path
from typing import Any

from starterbus.cli.arguments import device_args, fleet_arg, json_flag
from starterbus.cli.device_cmds import _user, prompt_hook
from starterbus.cli.output import emit_json, table
from starterbus.cli.target import recorded_name
from starterbus.core.audit import AuditLog
from starterbus.core.device import open_device
from starterbus.core.errors import ConfigurationError, StarterbusError
from starterbus.core.timestamps import iso_time, parse_iso_time
from starterbus.ops.history import EVENT_COLUMNS, SAMPLE_COLUMNS, HistoryStore

_RELATIVE = re.compile(r"(\d+(?:\.\d+)?)\s*(s|m|h|d|w)")
_UNITS = {"s": 1, "m": 60, "h": 3600, "d": 86400, "w": 604800}
FORCE_HELP = "start even though the starter is controlled from elsewhere (keypad, terminals, another master)"
_DEVICE_HELP = "{}: its name in the database (a fleet file's device name), or a fleet device's URL"


def add_parsers(sub: argparse._SubParsersAction[argparse.ArgumentParser], wanted: str) -> None:
    p = sub.add_parser("history", help="query a history database written by `poll --record` or `record`")
    p.add_argument("db", metavar="DB")
    p.add_argument("--device", metavar="NAME|URL", help=_DEVICE_HELP.format("only this device"))
    fleet_arg(p)
    p.add_argument("--since", metavar="T", help="from T: 2026-11-23T08:00 (local time) or an age: 90s, 10m, 2h, 1d")
    p.add_argument("--until", metavar="T", help="up to T (same forms)")
    p.add_argument("--events", action="store_true", help="the events (state changes, faults, writes...), not samples")
    p.add_argument("--kind", help="only events of this kind (state, fault, offline, online, write, command, start)")
    p.add_argument("--limit", type=int, metavar="N", help="the last N samples only")
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--csv", action="store_true", help="CSV on stdout")
    fmt.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(handler=cmd_history)

    p = sub.add_parser("record", help="record a start (status and currents) to CSV, SQLite and a PNG plot")
    device_args(p)
    p.add_argument("--start", action="store_true", help="send the start command (guarded); else wait for a start")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="directory for the CSV, starts.db and PNG")
    p.add_argument("--limit", type=float, default=60.0, metavar="S", help="stop after S seconds (default 60)")
    p.add_argument("--settle", type=float, default=1.0, metavar="S", help="keep recording S s after running")
    p.add_argument("--name", help="the device name in the database (default: the device name, else the URL)")
    p.add_argument("--no-plot", action="store_true", help="CSV and starts.db only (no matplotlib needed)")
    p.add_argument("--yes", "-y", action="store_true", help="start without asking (required without a terminal)")
    p.add_argument("--force", action="store_true", help=FORCE_HELP)
    p.add_argument("--audit-log", metavar="PATH", default=None, help="the JSON-lines audit log (see `write`)")
    p.set_defaults(handler=cmd_record)

    p = sub.add_parser("plot", help="draw a start from a history database as a PNG")
    p.add_argument("db", metavar="DB")
    p.add_argument("--device", required=True, metavar="NAME|URL", help=_DEVICE_HELP.format("the event's device"))
    fleet_arg(p)
    p.add_argument(
        "--event", required=True, type=int, metavar="N", help="a start or state event id (`history --events`)"
    )
    p.add_argument("-o", "--output", metavar="FILE", help="the PNG to write (default DB-DEVICE-event-N.png)")
    json_flag(p)
    p.set_defaults(handler=cmd_plot)


def parse_time(text: str | None, now: float | None = None) -> float | None:
    """An ISO 8601 time (local without a zone, as the JSON and CSV print it with one) or an age before now
    (``10m``, ``2h``, ``1d``)."""
    if text is None:
        return None
    now = time.time() if now is None else now
    match = _RELATIVE.fullmatch(text.strip().lower())
    if match:
        return now - float(match.group(1)) * _UNITS[match.group(2)]
    try:
        return parse_iso_time(text)
    except ValueError:
        raise ConfigurationError(f"{text!r} is neither a time (2026-11-23T08:00) nor an age (10m, 2h, 1d)") from None


def _stamp(t: float) -> str:
    return datetime.fromtimestamp(t).isoformat(timespec="milliseconds")


def cmd_history(args: argparse.Namespace) -> int:
    since, until = parse_time(args.since), parse_time(args.until)
    device = None if args.device is None else recorded_name(args.device, args.fleet)
    with HistoryStore(args.db, create=False) as store:
        known = store.devices()
        if device is not None and device not in known:
            raise ConfigurationError(
                f"{args.db}: nothing recorded of {device!r} (devices: {', '.join(known) or 'none'})"
            )
        if args.events or args.kind:
            rows = store.events(device=device, since=since, until=until, kind=args.kind)
            columns: tuple[str, ...] = EVENT_COLUMNS
        else:
            rows = store.samples(device=device, since=since, until=until, limit=args.limit)
            columns = SAMPLE_COLUMNS
    if args.json:
        rows = [{**row, "time": iso_time(row["time"])} for row in rows]
        emit_json({"events" if columns is EVENT_COLUMNS else "samples": rows})
    elif args.csv:
        out = csv.writer(sys.stdout)
        out.writerow(columns)
        for row in rows:
            out.writerow([iso_time(row[c]) if c == "time" else _cell(row[c]) for c in columns])
    elif columns is EVENT_COLUMNS:
        table(["id", "time", "device", "kind", "what"], [[r["id"], _stamp(r["time"]), r["device"], r["kind"], r["text"]]
                                                         for r in rows])  # fmt: skip
    else:
        table(
            ["time", "device", "state", "A", "B", "C", "values / error"],
            [[_stamp(r["time"]), r["device"], r["state"] or ("offline" if not r["online"] else "-"),
              *(_amps(r[f"current_{x}"]) for x in "abc"),
              r["error"] or " ".join(f"{k}={v.get('text', v.get('value'))}" for k, v in r["values"].items())]
             for r in rows],
        )  # fmt: skip
    return 0


def _amps(value: float | None) -> str:
    return "-" if value is None else f"{value:g}"


def _cell(value: Any) -> Any:
    import json

    return json.dumps(value, ensure_ascii=False) if isinstance(value, (dict, list)) else value


def cmd_record(args: argparse.Namespace) -> int:
    from starterbus.ops.extras import require
    from starterbus.ops.record import prepare_output, record_start, write_all

    if not args.no_plot:  # every precondition before the device is opened, let alone started
        require("plot", "record's PNG plot (--no-plot: CSV and starts.db only)")
    folder = prepare_output(args.output)
    device = open_device(
        args.url, args.model, audit=AuditLog(args.audit_log), actor=f"cli:{_user()}", confirm=prompt_hook(args)
    )
    try:
        with device:
            name = args.name or getattr(args, "device_name", None)
            rec = record_start(
                device,
                start=args.start,
                limit=args.limit,
                settle=args.settle,
                name=name,
                force=args.force,
                announce=lambda: _announce(args, device.describe()),
            )
    except (StarterbusError, KeyboardInterrupt):
        if args.start and any(o.result not in ("not sent", "refused") for o in device.guard.last_outcomes):
            outcome = device.guard.last_outcomes[-1]
            _motor_note(args, device.describe(), outcome.reached.state.value if outcome.reached else None)
        raise
    if not rec.points:
        raise ConfigurationError(f"nothing recorded: {rec.ended}")
    saved = write_all(rec, folder, plot=not args.no_plot)
    peak = max(((p.t, a) for p in rec.points for a in p.currents.values()), key=lambda x: x[1], default=None)
    ok = rec.ended == "running" and not saved.errors
    summary = {
        "device": rec.device,
        "samples": len(rec.points),
        "duration_s": rec.points[-1].t,
        "ended": rec.ended,
        "peak_a": peak[1] if peak else None,
        "peak_at_s": peak[0] if peak else None,
        "current_limit_a": rec.limit_a,
        "files": {k: str(v) for k, v in saved.files.items()},
        "not_saved": saved.errors,
    }
    if args.json:
        emit_json(summary)
    else:
        rate = len(rec.points) / rec.points[-1].t if rec.points[-1].t > 0 else 0.0
        print(f"{len(rec.points)} samples in {rec.points[-1].t:.2f} s ({rate:.1f}/s): {rec.ended}")
        if peak:
            limit = f" (current limit {rec.limit_a:.1f} A)" if rec.limit_a is not None else ""
            print(f"peak {peak[1]:.1f} A at {peak[0]:.2f} s{limit}")
        for kind, path in saved.files.items():
            print(f"{kind}: {path}")
    for why in saved.errors.values():
        print(f"starterbus: error: not saved: {why}", file=sys.stderr)
    if rec.commanded and not ok:
        _motor_note(args, rec.device, rec.state_at_end())
    return 130 if rec.ended.startswith("interrupted") else 0 if ok else 1


def _announce(args: argparse.Namespace, device: str) -> None:
    if not args.json:
        what = "starting" if args.start else "waiting for the next start of"
        print(f"{what} {device}; recording up to {args.limit:g} s", file=sys.stderr)


def _motor_note(args: argparse.Namespace, device: str, state: str | None) -> None:
    """After a failure, the motor this command started: whether it runs, and the command that stops it."""
    if state == "fault":  # tripped: the motor is off, and a reset clears the run command
        return
    target = getattr(args, "device_name", None) or args.url
    stop = f"starterbus stop {shlex.quote(target)}" + ("" if target != args.url else f" --model {args.model}")
    if state in ("ready", "stopped"):
        print(f"starterbus: {device} is {state}, but the start this command sent may still be set; clear it with: "
              f"{stop}", file=sys.stderr)  # fmt: skip
        return
    now = f"is {state}" if state in ("starting", "running", "stopping") else "may be running"
    print(f"starterbus: the motor of {device} {now} (this command started it); stop it with: {stop}", file=sys.stderr)


def cmd_plot(args: argparse.Namespace) -> int:
    from starterbus.ops.extras import require

    require("plot", "plot")
    from starterbus.ops.plot import plot_event

    device = recorded_name(args.device, args.fleet)
    out = args.output or str(Path(args.db).with_suffix("")) + f"-{device}-event-{args.event}.png"
    count = plot_event(args.db, device, args.event, out)
    if args.json:
        emit_json({"file": out, "device": device, "event": args.event, "samples": count})
    else:
        print(f"{out}: {count} samples of {device} around event {args.event}")
    return 0
