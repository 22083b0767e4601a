"""``read``, ``write``, ``status``, ``start|stop|reset``: one device through any transport.

Writes and commands are guarded: they ask for confirmation on a terminal and need ``--yes`` otherwise,
``--dry-run`` prints the frames instead of sending them, every attempt is appended to the audit log, and a
written parameter is read back (a mismatch is an error).
"""

from __future__ import annotations

import argparse
import sys

from starterbus.cli.output import emit_json, table
from starterbus.core.audit import AuditLog
from starterbus.core.device import Device, open_device
from starterbus.core.errors import StarterbusError, ValidationError
from starterbus.core.model import Value
from starterbus.core.status import Command, Status
from starterbus.core.transport import Capability


class ConfirmationRefused(StarterbusError):
    """A command that moves a motor or changes a parameter was not confirmed."""


class ReadBackMismatch(StarterbusError):
    """A written parameter reads back with another value."""


def _device(args: argparse.Namespace) -> Device:
    return open_device(args.url, args.model)


def cmd_read(args: argparse.Namespace) -> int:
    device = _device(args)
    keys = args.keys or [p.key for p in device.profile.measurements]
    with device:
        values = device.read(*keys)
    if args.json:
        emit_json(
            {
                "device": args.url,
                "model": device.profile.name,
                "values": [v.as_json() for v in values.values()],
            }
        )
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


def confirm(args: argparse.Namespace, question: str) -> None:
    """Ask on a terminal; without a terminal, require --yes. Raises ConfirmationRefused."""
    if getattr(args, "yes", False):
        return
    if not sys.stdin.isatty():
        raise ConfirmationRefused(f"{question.rstrip('?')}: refused without --yes (no terminal to confirm on)")
    answer = input(f"{question} [y/N] ").strip().lower()
    if answer not in ("y", "yes"):
        raise ConfirmationRefused("not confirmed; nothing sent")


def cmd_write(args: argparse.Namespace) -> int:
    device = _device(args)
    assignments = parse_assignments(args.assignments)
    checked = [device.validate_write(key, value) for key, value in assignments.items()]  # before anything opens
    if args.dry_run:
        rows: list[dict[str, object]] = []
        for point, raw in checked:
            frames = device.transport.preview_write(point, raw)
            rows.append({"key": point.key, "value": Value.from_raw(point, raw).text(), "frames": frames})
        _show_dry_run(args, rows)
        return 0
    audit = AuditLog(args.audit_log)
    text = ", ".join(f"{p.key} = {Value.from_raw(p, raw).text()}" for p, raw in checked)
    confirm(args, f"write {text} to {device.describe()}?")
    results: list[dict[str, object]] = []
    failed = False
    with device:
        can_read = Capability.READ_PARAMETERS in device.capabilities
        for point, raw in checked:
            new = Value.from_raw(point, raw)
            old = device.read_value(point) if can_read else None
            record: dict[str, object] = {
                "device": args.url,
                "model": device.profile.name,
                "action": "write",
                "key": point.key,
                "address": point.address,
                "old": old.text() if old else None,
                "new": new.text(),
            }
            try:
                device.write(point, new.value)
                if can_read:
                    back = device.read_value(point)
                    if back.raw != raw:
                        raise ReadBackMismatch(
                            f"{point.key}: wrote {new.text()} but read back {back.text()} from {device.describe()}"
                        )
                    record["read_back"] = back.text()
                record["result"] = "ok"
            except StarterbusError as exc:
                record["result"] = f"error: {exc}"
                failed = True
                audit.append(**record)
                results.append(record)
                raise
            audit.append(**record)
            results.append(record)
    if args.json:
        emit_json({"device": args.url, "model": device.profile.name, "written": results})
    else:
        table(
            ["key", "old", "new", "result"],
            [[r["key"], r["old"] or "-", r["new"], r["result"]] for r in results],
        )
    return 1 if failed else 0


def _show_dry_run(args: argparse.Namespace, rows: list[dict[str, object]]) -> None:
    if args.json:
        emit_json({"device": args.url, "dry_run": True, "would_send": rows})
        return
    print(f"dry run: nothing sent to {args.url}")
    for row in rows:
        what = row.get("key") or row.get("command")
        print(f"  {what} {row.get('value', '')}".rstrip())
        for frame in row["frames"]:  # type: ignore[attr-defined]
            print(f"    {frame}")


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
    if args.dry_run:
        _show_dry_run(args, [{"command": command.value, "frames": device.transport.preview_command(command)}])
        return 0
    confirm(args, f"{command.value} {device.describe()}?")
    audit = AuditLog(args.audit_log)
    record: dict[str, object] = {
        "device": args.url,
        "model": device.profile.name,
        "action": "command",
        "command": command.value,
    }
    with device:
        try:
            device.command(command)
        except StarterbusError as exc:
            audit.append(**record, result=f"error: {exc}")
            raise
        audit.append(**record, result="ok")
        status = device.status() if args.show_status else None
    if args.json:
        emit_json(
            {
                "device": args.url,
                "command": command.value,
                "result": "ok",
                "status": status.as_json() if status else None,
            }
        )
    else:
        print(f"{command.value}: sent to {device.describe()}")
        if status is not None:
            table(["", "status"], status_rows(status))
    return 0
