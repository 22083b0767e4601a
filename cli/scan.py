"""``starterbus scan URL``: the Modbus RTU devices on a line (speed, parity, unit ids, models), the units behind a
Modbus TCP gateway, the nodes on a DeviceNet bus (:mod:`starterbus.cli.scan_devicenet`), and a fleet file to
start from (docs/commissioning.md)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from starterbus.cli.arguments import json_flag
from starterbus.cli.output import emit_json, table
from starterbus.cli.scan_devicenet import mac_range
from starterbus.core.errors import ConfigurationError
from starterbus.core.profile import Profile
from starterbus.core.url import DeviceUrl
from starterbus.transports.modbus.scan import Found

DEFAULT_SPEEDS = (9600, 19200, 4800, 2400, 1200, 38400)  # the usual first
QUICK_UNITS = (1, 32)


def unit_range(text: str) -> tuple[int, int]:
    first, _, last = text.partition("-")
    try:
        lo, hi = int(first), int(last or first)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not A-B (e.g. 1-32)") from None
    if not 1 <= lo <= hi <= 247:
        raise argparse.ArgumentTypeError(f"{text!r}: unit ids are 1..247, the first no larger than the last")
    return lo, hi


def csv_list(text: str) -> list[str]:
    return [item.strip().upper() for item in text.split(",") if item.strip()]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "url",
        metavar="URL",
        help="modbus-rtu:///dev/ttyUSB0 (its query is ignored), modbus-tcp://HOST:PORT, devicenet://INTERFACE/CHANNEL",
    )
    p.add_argument("--models", help="the models to tell apart, comma-separated (default: every installed one)")
    p.add_argument("--baudrates", help="speeds to try, comma-separated (default: those the models offer)")
    p.add_argument("--parities", help="parities to try: E,N,O (default; --quick: E,N)")
    p.add_argument("--stopbits", default="1", help="stop bits to try: 1 (default), 2 or 1,2")
    p.add_argument("--units", type=unit_range, metavar="A-B", help="unit ids to try (default 1-247; --quick 1-32)")
    p.add_argument("--macs", type=mac_range, metavar="A-B", help="DeviceNet MAC ids to try (default 0-63)")
    p.add_argument("--quick", action="store_true", help="stop at the first setting where a unit answers")
    p.add_argument(
        "--timeout", type=float, help="seconds to wait for each answer (default 0.1; behind a Modbus TCP gateway 0.5)"
    )
    p.add_argument("-o", "--output", metavar="FLEET.toml", help="write a fleet file of what answered")
    p.add_argument("--force", action="store_true", help="replace an existing -o file")
    json_flag(p)


def _profiles(names: str | None) -> list[Profile]:
    from starterbus.core.registry import get_profile, profiles

    chosen = [n.strip() for n in names.split(",")] if names else profiles.names()
    found = [get_profile(name) for name in chosen]
    usable = [p for p in found if p.supports("modbus-rtu")]
    if not usable:
        raise ConfigurationError(f"scan: none of {', '.join(chosen)} has Modbus registers")
    return usable


def _ints(text: str, option: str) -> list[int]:
    try:
        return [int(x) for x in csv_list(text)]
    except ValueError:
        raise ConfigurationError(f"{option} {text}: not a comma-separated list of numbers") from None


def fleet_text(url: DeviceUrl, found: Sequence[Found]) -> str:
    """A fleet file: one bus per line setting that answered, one device per identified unit (others as
    comments)."""
    port = url.text.partition("?")[0]
    lines = [
        "# Written by `starterbus scan`: check the names and models, then `starterbus validate` this file",
        "# and `starterbus poll` it (docs/commissioning.md).",
    ]
    settings: dict[object, list[Found]] = {}
    for item in found:
        settings.setdefault(item.setting, []).append(item)
    for index, (setting, units) in enumerate(settings.items(), start=1):
        first = units[0].setting
        if first is None:  # behind a Modbus TCP gateway
            lines += ["", "[[bus]]", f'name = "gateway-{index}"', f'url = "{port}"']
        else:
            query = f"baudrate={first.baudrate}&parity={first.parity}&stopbits={first.stopbits}&timeout=0.3&retries=1"
            lines += ["", "[[bus]]", f'name = "line-{index}"', f'url = "{port}?{query}"']
        del setting
        for unit in units:
            if unit.model is None:
                lines += ["", f"  # unit {unit.unit} answered; model not identified: {unit.why}"]
                continue
            lines += ["", "  [[bus.device]]", f'  name = "{unit.model}-{unit.unit}"', f'  model = "{unit.model}"']
            lines.append(f"  address = {unit.unit}")
    return "\n".join(lines) + "\n"


def cmd_scan(args: argparse.Namespace) -> int:
    from starterbus.core.outfiles import check_target, write_atomically
    from starterbus.transports.modbus.scan import scan_line, settings

    url = DeviceUrl.parse(args.url)
    if url.transport not in ("modbus-rtu", "modbus-tcp", "devicenet"):
        raise ConfigurationError(
            f"scan {args.url}: scans a Modbus RTU line (modbus-rtu:///dev/ttyUSB0), a Modbus TCP gateway "
            "(modbus-tcp://HOST:502) or a DeviceNet bus (devicenet://socketcan/can0)"
        )
    target = check_target(args.output, force=args.force) if args.output else None
    if url.transport == "devicenet":
        from starterbus.cli.scan_devicenet import run_scan

        return run_scan(args, url, target)
    if args.macs:
        raise ConfigurationError("scan: --macs is for a DeviceNet bus")
    if url.transport == "modbus-tcp":
        return _scan_gateway(args, url, target)
    models = _profiles(args.models)
    if args.baudrates:
        speeds = _ints(args.baudrates, "--baudrates")
    else:
        from starterbus.transports.modbus.settings import modbus_settings

        offered = {rate for p in models for rate in modbus_settings(p).baudrates}
        speeds = [rate for rate in DEFAULT_SPEEDS if rate in offered] or [9600]
    parities = csv_list(args.parities) if args.parities else (["E", "N"] if args.quick else ["E", "N", "O"])
    if not set(parities) <= {"E", "N", "O"}:
        raise ConfigurationError(f"--parities {args.parities}: each is E, N or O")
    lo, hi = args.units or (QUICK_UNITS if args.quick else (1, 247))
    tries = settings(speeds, parities, _ints(args.stopbits, "--stopbits"))

    def progress(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    found = []
    try:
        found = scan_line(url, models, tries, list(range(lo, hi + 1)), timeout=args.timeout or 0.1, quick=args.quick,
                          progress=progress)  # fmt: skip
    except KeyboardInterrupt:
        print("scan: interrupted; nothing written", file=sys.stderr)
        return 130
    if target is not None:
        write_atomically(target, fleet_text(url, found), replace=args.force)
    _report(args, url, target, found)
    return 0 if found else 1


def _report(args: argparse.Namespace, url: DeviceUrl, target: object, found: Sequence[Found]) -> None:
    rows = [(f.unit, f.setting.describe() if f.setting else "gateway", f.model or "?", f.why) for f in found]
    if args.json:
        emit_json({
            "url": url.text, "output": str(target) if target else None,
            "found": [{"unit": f.unit, **_line_json(f), "model": f.model, "candidates": list(f.candidates),
                       "why": f.why} for f in found],
        })  # fmt: skip
    elif rows:
        table(("unit", "line", "model", "why"), rows)
    else:
        print("scan: no unit answered", file=sys.stderr)


def _line_json(found: Found) -> dict[str, object]:
    if found.setting is None:
        return {}
    return {"baudrate": found.setting.baudrate, "parity": found.setting.parity, "stopbits": found.setting.stopbits}


def _scan_gateway(args: argparse.Namespace, url: DeviceUrl, target: Path | None) -> int:
    """The units behind a Modbus TCP gateway: one read each (no line settings to try)."""
    from starterbus.core.outfiles import write_atomically
    from starterbus.transports.modbus.scan import scan_gateway

    if args.baudrates or args.parities or args.stopbits != "1":
        raise ConfigurationError("scan modbus-tcp: --baudrates, --parities and --stopbits are the gateway's settings")
    models = _profiles(args.models)
    lo, hi = args.units or (QUICK_UNITS if args.quick else (1, 247))

    def progress(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    try:
        found = scan_gateway(url, models, list(range(lo, hi + 1)), timeout=args.timeout or 0.5, progress=progress)
    except KeyboardInterrupt:
        print("scan: interrupted; nothing written", file=sys.stderr)
        return 130
    if target is not None:
        write_atomically(target, fleet_text(url, found), replace=args.force)
    _report(args, url, target, found)
    return 0 if found else 1
