"""``starterbus watch URL|NAME [KEY...]``: one device, status and chosen points, refreshed in place (as mbpoll)."""

from __future__ import annotations

import argparse
import sys
import threading
import time
from typing import TextIO

from starterbus.cli.arguments import device_args
from starterbus.cli.output import emit_json_line, paint, table, use_colour
from starterbus.core.device import Device, open_device
from starterbus.core.errors import StarterbusError, TimeoutError, TransportError
from starterbus.core.fault_codes import value_text
from starterbus.core.status import MotorState, Status
from starterbus.core.timestamps import iso_time
from starterbus.core.transport import Capability


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser], wants: str) -> None:
    p = sub.add_parser(
        "watch",
        help="watch one device: status and chosen points, refreshed in place",
        description="Poll one device and show its status and points, refreshed in place on a terminal "
        "(one block per poll on a pipe, one JSON line per poll with --json).",
    )
    device_args(p)
    p.add_argument("keys", nargs="*", metavar="KEY", help="points to show besides the status (default: measurements)")
    p.add_argument("--interval", type=float, default=1.0, metavar="S", help="seconds between polls (default 1)")
    p.add_argument("--once", action="store_true", help="poll once, print, exit")
    p.add_argument("--count", type=int, default=None, metavar="N", help="stop after N polls")
    p.set_defaults(handler=cmd_watch, rest_into="keys")


def cmd_watch(args: argparse.Namespace) -> int:
    device = open_device(args.url, args.model)
    out = sys.stdout
    in_place = out.isatty() and not args.json and not args.once
    count = 1 if args.once else args.count
    stop = threading.Event()
    polls, widths = 0, None
    with device:
        keys = args.keys or [p.key for p in device.profile.measurements]
        if Capability.READ_MEASUREMENTS not in device.capabilities and not args.keys:
            keys = []
        while True:
            started = time.monotonic()
            status, values, error = poll(device, keys)
            polls += 1
            if args.json:
                emit_json_line(
                    {
                        "device": args.url,
                        "time": iso_time(status.timestamp if status else None),
                        "status": status.as_json() if status else None,
                        "values": values,
                        "error": error,
                    }
                )
            else:
                widths = show(device, status, values, error, out, in_place, widths)
            out.flush()
            if count is not None and polls >= count:
                return 1 if error else 0
            stop.wait(max(0.0, args.interval - (time.monotonic() - started)))


def poll(device: Device, keys: list[str]) -> tuple[Status | None, list[dict[str, object]], str | None]:
    try:
        status = device.status() if Capability.STATUS in device.capabilities else None
        read = device.read(*keys).values() if keys else ()
        values = [v.as_json() | {"text": value_text(device.profile, v)} for v in read]
        return status, values, None
    except (TimeoutError, TransportError) as exc:
        return None, [], f"communication: {exc}"
    except StarterbusError as exc:
        return None, [], str(exc)


def show(
    device: Device,
    status: Status | None,
    values: list[dict[str, object]],
    error: str | None,
    out: TextIO,
    in_place: bool,
    widths: list[int] | None,
) -> list[int]:
    if in_place:
        out.write("\x1b[H\x1b[J")
    head = f"{device.describe()}  {time.strftime('%H:%M:%S')}"
    if status is not None:
        state = status.state
        style = "fault" if state is MotorState.FAULT else ("warning" if status.warning else None)
        text = state.value + (f"  fault {status.fault_code}: {status.fault_text}" if status.fault else "")
        head += "  " + (paint(text, style) if use_colour(out) else text)
    out.write(head + "\n")
    if error:
        out.write((paint(error, "offline") if use_colour(out) else error) + "\n")
    rows = [[v["address"], v["key"], v["text"]] for v in values]
    if status is not None:
        rows += [["", f"current_{k}", v.text()] for k, v in status.currents.items()]
    return table(["address", "key", "value"], rows, out, widths=widths)
