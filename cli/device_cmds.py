"""``read``, ``write``, ``status``, ``start|stop|reset``: one device through any transport."""

from __future__ import annotations

import argparse

from starterbus.cli.output import emit_json, table
from starterbus.core.device import Device, open_device
from starterbus.core.errors import ValidationError
from starterbus.core.status import Command, Status


def _device(args: argparse.Namespace) -> Device:
    return open_device(args.url, args.model)


def cmd_read(args: argparse.Namespace) -> int:
    device = _device(args)
    keys = args.keys or [p.key for p in device.profile.measurements]
    with device:
        values = device.read(*keys)
    if args.json:
        emit_json({"device": args.url, "model": device.profile.name, "values": [v.as_json() for v in values.values()]})
    else:
        table(
            ["address", "key", "name", "value", "raw"],
            [[v.point.address, v.key, v.point.name_en, v.text(), v.raw] for v in values.values()],
        )
    return 0


def parse_assignments(items: list[str]) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise ValidationError(f"{item!r} is not KEY=VALUE")
        out[key.strip()] = value.strip()
    return out


def cmd_write(args: argparse.Namespace) -> int:
    device = _device(args)
    assignments = parse_assignments(args.assignments)
    for key, value in assignments.items():  # validate everything before opening anything
        device.validate_write(key, value)
    with device:
        written = device.write_many(assignments)
    if args.json:
        emit_json({"device": args.url, "model": device.profile.name, "written": [v.as_json() for v in written]})
    else:
        table(["key", "written"], [[v.key, v.text()] for v in written])
    return 0


def status_rows(status: Status) -> list[list[object]]:
    def flag(value: bool | None) -> str:
        return "-" if value is None else ("yes" if value else "no")

    rows: list[list[object]] = [
        ["state", status.state.value],
        ["fault", f"{status.fault_code}: {status.fault_text}" if status.fault else "no"],
        ["ready", flag(status.ready)],
        ["soft starting", flag(status.starting)],
        ["running", flag(status.running)],
        ["soft stopping", flag(status.stopping)],
        ["bus control", flag(status.bus_control)],
        ["warning", flag(status.warning)],
        ["at reference", flag(status.at_reference)],
    ]
    if status.mains_voltage is not None:
        rows.append(["mains voltage", flag(status.mains_voltage)])
    for phase, value in status.currents.items():
        rows.append([f"current {phase.upper()}", value.text()])
    for name, raw in status.raw.items():
        rows.append([name, f"0x{raw:04X}"])
    if status.unknown_bits:
        rows.append(["unknown bits", f"0x{status.unknown_bits:04X}"])
    return rows


def cmd_status(args: argparse.Namespace) -> int:
    device = _device(args)
    with device:
        status = device.status()
    if args.json:
        emit_json({"device": args.url, "model": device.profile.name, "status": status.as_json()})
    else:
        table(["", device.describe()], status_rows(status))
    return 0


def cmd_command(args: argparse.Namespace) -> int:
    device = _device(args)
    command = Command(args.command)
    with device:
        device.command(command)
        status = device.status() if args.show_status else None
    if args.json:
        emit_json({"device": args.url, "command": command.value, "result": "ok",
                   "status": status.as_json() if status else None})  # fmt: skip
    else:
        print(f"{command.value}: sent to {device.describe()}")
        if status is not None:
            table(["", "status"], status_rows(status))
    return 0
