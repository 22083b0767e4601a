"""``read``, ``write``, ``status``, ``start|stop|reset``: one device through any transport.

A thin shell over the core's guarded path (:mod:`starterbus.core.guarded`): the CLI supplies the
confirmation (a prompt on a terminal, ``--yes`` otherwise), the audit log and who asks; validation, the
certainty and state rules, the audit record of the outcome and the read-back (value or state reached) are
the core's. ``--dry-run`` prints the frames instead of sending them.
"""

from __future__ import annotations

import argparse
import getpass
import sys
from collections.abc import Iterable
from typing import TextIO

from starterbus.cli.output import emit_json, table
from starterbus.core.audit import AuditLog
from starterbus.core.device import Device, open_device
from starterbus.core.errors import UnsupportedOperationError, ValidationError
from starterbus.core.fault_codes import value_text
from starterbus.core.guarded import (
    Confirm,
    ConfirmationRefused,
    GuardedOperationError,
    Outcome,
    Proposal,
    UncertainValueError,
)
from starterbus.core.model import PointDef, Value
from starterbus.core.status import Command, Status


def _device(args: argparse.Namespace) -> Device:
    return open_device(args.url, args.model)


def cmd_read(args: argparse.Namespace) -> int:
    if args.raw:
        from starterbus.cli.raw_cmds import cmd_read_raw

        return cmd_read_raw(args)
    device = _device(args)
    keys = args.keys or [p.key for p in device.profile.measurements]
    with device:
        values = device.read(*keys)
    if args.json:
        emit_json(
            {
                "device": args.url,
                "model": device.profile.name,
                "values": [{**v.as_json(), "text": value_text(device.profile, v)} for v in values.values()],
            }
        )
    else:
        table(
            ["address", "key", "name", "value", "raw"],
            [[v.point.address, v.key, v.point.name_en, value_text(device.profile, v), v.raw] for v in values.values()],
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


def prompt_hook(args: argparse.Namespace) -> Confirm:
    """The CLI's confirmation: ``--yes``, else a question on a terminal showing the raw codes and frames."""

    def ask(proposal: Proposal) -> bool:
        if getattr(args, "yes", False):
            return True
        if not sys.stdin.isatty():
            raise ConfirmationRefused(
                f"{proposal.question().rstrip('?')}: refused without --yes (no terminal to confirm on)"
            )
        for planned in proposal.writes:
            if planned.uncertainty:
                print(f"  note: {planned.uncertainty}", file=sys.stderr)
        for frame in proposal.frames:
            print(f"  frame: {frame}", file=sys.stderr)
        print(f"{proposal.question()} [y/N] ", end="", file=sys.stderr, flush=True)  # stdout may be JSON for a pipe
        answer = sys.stdin.readline().strip().lower()
        return answer in ("y", "yes")

    return ask


def _guarded_device(args: argparse.Namespace) -> Device:
    return open_device(
        args.url, args.model, audit=AuditLog(args.audit_log), actor=f"cli:{_user()}", confirm=prompt_hook(args)
    )


def _user() -> str:
    try:
        return getpass.getuser()
    except (KeyError, OSError):
        return "?"


def cmd_write(args: argparse.Namespace) -> int:
    if args.raw:
        from starterbus.cli.raw_cmds import cmd_write_raw

        return cmd_write_raw(args)
    device = _guarded_device(args)
    assignments = parse_assignments(args.assignments)
    checked = [device.validate_write(key, value) for key, value in assignments.items()]  # before anything opens
    uncertain = [u for p, raw in checked if (u := p.uncertainty(raw))]
    if uncertain and not args.accept_uncertain:
        raise UncertainValueError("; ".join(uncertain) + " (acknowledge with --accept-uncertain)")
    if args.dry_run:
        show_dry_run(args, write_previews(device, checked))
        return 0
    with device:
        try:
            outcomes = device.write_many(assignments, accept_uncertain=args.accept_uncertain)
        except GuardedOperationError:
            _show_outcomes(args, device, device.guard.last_outcomes, to=sys.stderr)
            raise
    _show_outcomes(args, device, outcomes)
    return 0


def _show_outcomes(args: argparse.Namespace, device: Device, outcomes: list[Outcome], to: TextIO | None = None) -> None:
    if args.json:
        if to is None:
            emit_json({"device": args.url, "model": device.profile.name, "written": [o.as_json() for o in outcomes]})
        return
    rows = [
        [o.key, o.old.text() if o.old else "-", o.new.text() if o.new else "-",
         o.read_back.text() if o.read_back else "-", o.result]
        for o in outcomes
    ]  # fmt: skip
    table(["key", "old", "new", "read back", "result"], rows, out=to)


def write_previews(device: Device, writes: Iterable[tuple[PointDef, int]]) -> list[dict[str, object]]:
    """What ``--dry-run`` shows of each write: the key, the value, the raw code and the exact frames."""
    return [
        {"key": point.key, "value": Value.from_raw(point, raw).text(), "raw": raw,
         "frames": device.transport.preview_write(point, raw)}
        for point, raw in writes
    ]  # fmt: skip


def show_dry_run(args: argparse.Namespace, rows: list[dict[str, object]], **extra: object) -> None:
    """What would be sent, and nothing sent; ``extra`` goes into the ``--json`` document."""
    if args.json:
        emit_json({"device": args.url, "dry_run": True, **extra, "would_send": rows})
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
    device = _guarded_device(args)
    command = Command(args.command)
    holding = args.hold or args.hold_for is not None
    if args.dry_run:
        show_dry_run(args, [{"command": command.value, "frames": device.transport.preview_command(command)}])
        return 0
    if command is Command.START and device.transport.run_needs_connection and not holding:
        raise UnsupportedOperationError(
            f"{device.transport.name}: the run command lives only while this program holds the connection (when "
            "`start` exits, the device's watchdog soft-stops the motor); use --hold (run until Ctrl-C, then a "
            "reported soft stop) or --hold-for SECONDS, or command it from a long-running `poll`/`serve`"
        )
    with device:
        try:
            outcome = device.command(command, timeout=args.wait, force=args.force)
        except GuardedOperationError as exc:
            if exc.outcomes and args.json:
                emit_json({"device": args.url, "command": command.value, **exc.outcomes[0].as_json()})
            raise
        _show_command(args, device, outcome)
        if holding and command is Command.START:
            return _hold(args, device)
    return 0


def _show_command(args: argparse.Namespace, device: Device, outcome: Outcome) -> None:
    if outcome.overridden:
        print(f"starterbus: warning: --force: sent although {outcome.overridden}", file=sys.stderr)
    if args.json:
        emit_json({"device": args.url, "command": outcome.action, **outcome.as_json()})
        return
    state = outcome.reached.state.value if outcome.reached else "?"
    print(f"{outcome.action}: {outcome.result}, {device.describe()} is {state}")
    if outcome.reached is not None and args.show_status:
        table(["", "status"], status_rows(outcome.reached))


def _hold(args: argparse.Namespace, device: Device) -> int:
    """Keep the connection (and so the run command) until Ctrl-C or --hold-for, then soft-stop and report."""
    clock = device.guard.clock
    until = None if args.hold_for is None else clock() + args.hold_for
    interrupted = False
    try:
        while until is None or clock() < until:
            status = device.status()
            if args.json:
                emit_json({"device": args.url, "holding": True, "status": status.as_json()})
            else:
                currents = " ".join(f"{k.upper()} {v.text()}" for k, v in status.currents.items())
                print(f"holding: {status.state.value} {currents}".rstrip(), file=sys.stderr)
            device.guard.sleep(min(0.5, max(0.0, until - clock())) if until is not None else 0.5)
    except KeyboardInterrupt:
        interrupted = True
    outcome = device.command(Command.SOFT_STOP, timeout=args.wait, force=args.force)
    _show_command(args, device, outcome)
    return 130 if interrupted else 0
